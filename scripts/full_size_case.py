"""One full-size hidden-effect case of ``tests/test_diagnose_job.py::test_full_size``, with
its diagnosis written as JSON.

The same campaign (12 healthy rig runs over 0.25-0.50 m/s, the effect drawn by
``from_seed(seed)``), the same ``diagnose_campaign`` call with the base model fitted on the
case's own runs, and the same checks of the verdict and of the key parameter as the test;
what the test does not keep is saved: every candidate's gain, the stage times and, for a
failed check, its message. Several cases run side by side as separate processes (each
diagnosis uses two threads), as on the lent machine of session 13::

    python scripts/full_size_case.py frame_mode 3 out/full_size
    taskset -c 2,3 python scripts/full_size_case.py rail_waviness 3 out/full_size &

Writes ``OUT/NAME-SEED.json`` and prints ``NAME SEED VERDICT PASSED SECONDS``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import traceback
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent


def run_case(name: str, seed: int) -> dict[str, Any]:
    """The test's case ``(name, seed)``: its verdict, whether the test's checks pass, why not."""
    sys.path.insert(0, str(ROOT / "tests"))
    import test_diagnose_job as cases  # the test's own campaign, door and checks

    started = time.perf_counter()
    result: dict[str, Any] = {"name": name, "seed": seed}
    try:
        recording, rig = cases.record(name, seed, cases.SPEEDS_SLOW)
        diagnosis = cases.diagnose_campaign(
            cases.DOOR,
            recording.campaign,
            seed=seed,
            progress=False,
            catalogue=cases.DOOR_CATALOGUE,
        )
        result["verdict"] = diagnosis.verdict
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
    args = parser.parse_args()

    import jax

    jax.config.update("jax_enable_x64", True)
    jax.config.update("jax_numpy_dtype_promotion", "strict")  # as the tests run
    result = run_case(args.name, args.seed)
    result["provenance"] = provenance()
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / f"{args.name}-{args.seed}.json"
    path.write_text(json.dumps(result, indent=1, default=str))
    verdict, passed = result.get("verdict"), result.get("passed")
    print(args.name, args.seed, verdict, passed, round(result["seconds"]), flush=True)


if __name__ == "__main__":
    main()
