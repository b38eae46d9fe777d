"""One full-size hidden-effect case of ``tests/test_diagnose_job.py::test_full_size``, with
its diagnosis written as JSON.

The same campaign (12 healthy rig runs over 0.25-0.50 m/s, the effect drawn by
``from_seed(seed)``), the same ``diagnose_campaign`` call with the base model fitted on the
case's own runs, and the same checks of the verdict and of the key parameter as the test;
what the test does not keep is saved: every candidate's gain, the stage times and, for a
failed check, its message. Several cases run side by side as separate processes (each
diagnosis uses two threads), for example pinned to cores on a larger machine::

    python scripts/full_size_case.py frame_mode 3 out/full_size
    taskset -c 2,3 python scripts/full_size_case.py rail_waviness 3 out/full_size &

With ``--ceiling`` the case also gets its *ceiling*: the rig records the same runs again with
the same key and without the effect (the same parameter scatter, speeds and noise), the
change of each run's log PSD (with the effect less without it) is added to the base model's
spectra, a model that knows the effect exactly, and that model is judged on the diagnosis's
own setup and folds by its own held-out rule (changed bins, local scatter, the tracking flag
of the effect's candidate). A refit that gains less than its ceiling leaves something to
find; a ceiling under the rule's 4 standard errors says the effect is too weak for the
judgement at this size, whatever a refit does (results/diagnosis_full_size.md has the ceilings).

Writes ``OUT/NAME-SEED.json`` (with the base fit's point, so that a case can be judged again
without fitting) and prints ``NAME SEED VERDICT PASSED SECONDS`` (and the effect's refit and
ceiling in standard errors with ``--ceiling``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import traceback
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def ceiling_gain(
    setup: Any, folds: Any, tracking: bool, clean_signals: np.ndarray
) -> tuple[Any, list[int]]:
    """The held-out :class:`~bayesdoor.diagnose.Gain` of the base model plus the rig's own
    effect (``setup.spectra.measured`` less the log PSD of ``clean_signals``, the same runs
    recorded without it), judged as the diagnosis judges a refit
    (:func:`~bayesdoor.diagnose.judge_folds`); and the held-out runs in the gain's order."""
    from bayesdoor.diagnose import windowed_log_psd
    from bayesdoor.diagnose._held_out import judge_folds

    spectra = setup.spectra
    _, clean, _ = windowed_log_psd(
        clean_signals, spectra.fs, spectra.t_start, spectra.t_stop, nperseg=spectra.nperseg
    )
    model = setup.base_spectra + (spectra.measured - clean[..., spectra.keep])
    gain = judge_folds(setup, [model] * len(folds), folds, tracking=tracking)
    return gain, list(gain.runs)


def _ceiling(
    cases: Any, name: str, seed: int, recording: Any, seen: dict[str, Any]
) -> dict[str, Any]:
    """The case's ceiling on the first setup and folds a refit was judged on; ``recording``
    is the case's own, with the effect."""
    from bayesdoor.diagnose._held_out import tracks_speed
    from bayesdoor.diagnose._measured import Measured
    from bayesdoor.inference import calibration_runs

    if name == cases.NONE:
        return {"ceiling_note": "nothing hidden: no ceiling"}
    if "setup" not in seen:
        return {"ceiling_note": "no candidate was refitted: no setup to judge a ceiling on"}
    clean, _ = cases.record(cases.NONE, seed, cases.SPEEDS_SLOW)  # the same key
    if recording.truth["runs"] != clean.truth["runs"]:
        raise RuntimeError(
            f"{name} seed {seed}: the two recordings' run scatter or speeds differ, so their "
            "difference is not the effect's alone"
        )
    setup, folds = seen["setup"]
    signature = {c.name: c.signature for c in cases.DOOR_CATALOGUE.candidates}[name]
    tracking = tracks_speed(signature)
    runs = calibration_runs(clean.campaign)
    clean_signals = Measured.of(cases.DOOR, clean.campaign, runs).signals
    gain, held = ceiling_gain(setup, folds, tracking, clean_signals)
    return {
        "ceiling_gain": {**gain.to_json(), "delta_elpd_runs": held},
        "ceiling_tracking": tracking,
    }


def run_case(name: str, seed: int, *, ceiling: bool = False) -> dict[str, Any]:
    """The test's case ``(name, seed)``: its verdict, whether the test's checks pass, why not;
    with ``ceiling`` also the held-out gain of the base model plus the rig's own effect."""
    sys.path.insert(0, str(ROOT / "tests"))
    import test_diagnose_job as cases  # the test's own campaign, door and checks

    import bayesdoor.diagnose._candidates as candidates

    started = time.perf_counter()
    result: dict[str, Any] = {"name": name, "seed": seed}
    seen: dict[str, Any] = {}
    original = candidates._judge_refits

    def recorded(setup, proposal, folds, fits, **kwargs):  # type: ignore[no-untyped-def]
        seen.setdefault("setup", (setup, folds))
        return original(setup, proposal, folds, fits, **kwargs)

    try:
        recording, rig = cases.record(name, seed, cases.SPEEDS_SLOW)
        candidates._judge_refits = recorded
        try:
            diagnosis = cases.diagnose_campaign(
                cases.DOOR,
                recording.campaign,
                seed=seed,
                progress=False,
                catalogue=cases.DOOR_CATALOGUE,
            )
        finally:
            candidates._judge_refits = original
        result["verdict"] = diagnosis.verdict
        if diagnosis.fit is not None:
            result["fit_point"] = {k: float(v) for k, v in diagnosis.fit.point.items()}
        if ceiling:
            result.update(_ceiling(cases, name, seed, recording, seen))
        passed = diagnosis.verdict == name
        if passed and name != cases.NONE:
            try:
                cases.check_parameters(name, diagnosis.cause(name), recording, rig)
            except AssertionError as err:
                passed = False
                result["parameter_check"] = str(err)
        result["passed"] = passed
        result["diagnosis"] = diagnosis.to_json()
    except Exception:
        result["error"] = traceback.format_exc()
    result["seconds"] = time.perf_counter() - started
    return result


def provenance() -> str:
    """Where a case ran: the commit, JAX's version and the CPUs this process may use."""
    import os
    import platform

    import jax
    from _cases import code_version

    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return f"{code_version()}, JAX {jax.__version__}, {cpus} CPUs, {platform.node()}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("name", help="a catalogue effect, or none")
    parser.add_argument("seed", type=int)
    parser.add_argument("out", type=Path, help="folder of the JSON results")
    parser.add_argument(
        "--ceiling",
        action="store_true",
        help="also judge the base model plus the rig's own effect (a second recording)",
    )
    args = parser.parse_args()

    import jax

    jax.config.update("jax_enable_x64", True)
    jax.config.update("jax_numpy_dtype_promotion", "strict")  # as the tests run
    where = provenance()  # before the run: the code it imports is the code of its start
    result = run_case(args.name, args.seed, ceiling=args.ceiling)
    result["provenance"] = where
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / f"{args.name}-{args.seed}.json"
    path.write_text(json.dumps(result, indent=1, default=str))
    verdict, passed = result.get("verdict"), result.get("passed")
    words = [args.name, args.seed, verdict, passed, round(result["seconds"])]
    if args.ceiling:
        causes = (result.get("diagnosis") or {}).get("causes", [])
        cause = next((c for c in causes if c["name"] == args.name), None)
        refit = _se(cause.get("gain") if cause else None)
        words += [f"refit {refit}", f"ceiling {_se(result.get('ceiling_gain'))}"]
    print(*words, flush=True)


def _se(gain: dict[str, Any] | None) -> str:
    """A gain in standard errors, ``-`` when there is none."""
    if not gain or not gain.get("elpd_se"):
        return "-"
    return f"{gain['delta_elpd'] / gain['elpd_se']:.2f} SE"


if __name__ == "__main__":
    main()
