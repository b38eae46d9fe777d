"""Contact-law ablation: one posterior per law on the demo campaign's calibration runs.

The design (so that nine full-size posteriors fit in well under an hour on two cores):

1. **One shared search.** CMA-ES on the paper's J with the contact law searched as an integer
   variable, at the full settings of the campaign's own fit (``FitSettings()``: 1500
   evaluations, two IPOP restarts). Its optimum and law are the reference.
2. **Per law, a warm-started fit.** For each of the nine laws, ``fit_campaign(method="nuts",
   problem=FitProblem(fixed={"I": k}, x0=...))`` starts CMA-ES at the reference optimum with
   a smaller step and budget (``cmaes_sigma0`` 0.1 of each range, 240 evaluations, no
   restart). The start's c_r
   is the value whose hysteresis factor xi(c_r) equals the reference law's: in the persistent
   rolling contact of healthy runs the contact damping is xi(c_r) K d^n / floor, so the data
   fix xi, not c_r (see :func:`matched_c_r`). Then the surrogate and NUTS of
   :func:`bayesdoor.inference.fit_campaign` at full size, with 4 chains x 1000 kept draws.
3. **Comparison.** The fitted J (at the CMA-ES optimum and at the posterior mean), posterior
   means and sds, PSIS-LOO ELPD with its SE and stacking weights (``arviz.compare``).

Writes ``results/contact_law_ablation.md`` (the block between the markers is regenerated; the
discussion around it is kept) and ``results/contact_law_ablation.json``.

The fits run in a pool of ``--workers`` spawned processes (XLA on one thread each, the
project's compilation cache shared); each saves its fit (``FitResult.save``) under the work
folder. With ``--work DIR`` a fit already there with the same settings, seed and law is read
back instead of refitted, so an interrupted run resumes where it stopped.

Usage::

    .venv/bin/python scripts/contact_law_ablation.py [--quick] [--seed N] [--workers W]
        [--work DIR] [--laws 1 2 ...] [--out FILE]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import multiprocessing
import os
import sys
import tempfile
import time
import warnings
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np
from scipy.optimize import brentq

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "results" / "contact_law_ablation.md"
LAWS = tuple(range(1, 10))

#: the per-law warm start: a fifth of the shared search's budget at 0.4 of its step is enough
#: to move from a neighbouring optimum (the xi-matched start) to the law's own
WARM_SIGMA0 = 0.1
WARM_EVALS = 240
#: kept NUTS draws per chain: the gates need bulk ESS >= 400 for every parameter; the timing
#: fit (law 3, 4 x 500) passed with R-hat 1.0096, too close to 1.01 for nine fits
NUM_SAMPLES = 1000


def settings_for(stage: str, quick: bool):
    """The ``FitSettings`` of the shared search (``"reference"``) or of a per-law fit.

    ``quick`` starts from ``FitSettings.quick()`` (1 s of motion, small surrogate, 2 chains x
    150 draws): for smoke tests, not converged.
    """
    from bayesdoor.inference import FitSettings

    base = FitSettings.quick() if quick else FitSettings()
    if stage == "reference":
        return base
    return dataclasses.replace(
        base,
        cmaes_sigma0=WARM_SIGMA0,
        cmaes_max_evals=min(WARM_EVALS, base.cmaes_max_evals),
        cmaes_restarts=0,
        num_samples=base.num_samples if quick else NUM_SAMPLES,
    )


def matched_c_r(law: int, xi: float, lower: float, upper: float) -> float:
    """The c_r in ``[lower, upper]`` at which ``law``'s hysteresis factor equals ``xi``.

    Every law's xi(c_r) falls monotonically over the door's c_r range; when ``xi`` lies outside
    the law's reach there, the bound that comes closest is returned (Lee and Wang's xi tops
    out at 0.30 at c_r = 0.6).

    Raises
    ------
    ValueError
        If ``lower >= upper``.
    """
    from bayesdoor.door.contact import get_law

    if not lower < upper:
        raise ValueError(f"lower={lower} must lie below upper={upper}")

    def gap(c_r: float) -> float:
        return float(get_law(law).hysteresis_factor(jnp.asarray(c_r))) - xi

    if gap(lower) <= 0.0:
        return lower
    if gap(upper) >= 0.0:
        return upper
    return float(brentq(gap, lower, upper, xtol=1e-12))


def warm_start(reference: dict[str, float], reference_law: int, law: int, bounds) -> dict:
    """The reference optimum with c_r moved to deliver the reference law's xi under ``law``."""
    from bayesdoor.door.contact import get_law

    xi = float(get_law(reference_law).hysteresis_factor(jnp.asarray(reference["c_r"])))
    start = {k: v for k, v in reference.items() if k != "I"}
    start["c_r"] = matched_c_r(law, xi, *bounds)
    return start


def damping_table(results) -> str:
    """Per law: the posterior of c_r and of the hysteresis factor xi(c_r) it implies.

    In persistent rolling contact the latched approach velocity sits at its floor, so the
    damping is xi(c_r) K d^n / floor: what the data can fix is xi, not which law produced it.
    """
    from bayesdoor.door.contact import LAW_NAMES, get_law

    lines = [
        "",
        "| law | name | c_r mean (sd) | xi(c_r) mean (sd) | xi range over c_r in [0.6, 0.95] |",
        "|---|---|---|---|---|",
    ]
    for law, r in results.items():
        c_r = r.posterior_draws()["c_r"]
        xi = np.asarray(get_law(law).hysteresis_factor(jnp.asarray(c_r)))
        ends = np.asarray(get_law(law).hysteresis_factor(jnp.array([0.95, 0.6])))
        lines.append(
            f"| {law} | {LAW_NAMES[law - 1]} | {c_r.mean():.3f} ({c_r.std():.3f}) | "
            f"{xi.mean():.3f} ({xi.std():.3f}) | {ends[0]:.3f} to {ends[1]:.3f} |"
        )
    return "\n".join(lines) + "\n"


def search_table(starts: dict[int, dict], results, seconds: dict[int, float]) -> str:
    """Per law: how its optimum was found, its J there and at the posterior mean, the gates."""
    lines = [
        "",
        "| law | start c_r (xi-matched) | CMA-ES evals | J at optimum | J at posterior mean | "
        "surrogate boxes | max R-hat | min bulk ESS | divergences | minutes |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for law, r in results.items():
        d = r.diagnostics
        boxes = 1 + sum(n.startswith("surrogate box") and "moved" in n for n in r.notes)
        minutes = f"{seconds[law] / 60:.1f}" if law in seconds else "(earlier run)"
        lines.append(
            f"| {law} | {starts[law]['c_r']:.4f} | {r.cmaes.evaluations} | {r.cmaes.f_best:.4f} | "
            f"{r.j:.4f} | {boxes} | {d.rhat_max:.4f} | {d.ess_bulk_min:.0f} | "
            f"{d.divergences} | {minutes} |"
        )
    return "\n".join(lines) + "\n"


def _configure_jax() -> None:
    from bayesdoor import configure_jax

    configure_jax(ROOT / ".jax_cache")


def _load(campaign_file: Path | None):
    from bayesdoor.door.datasets import load_demo_campaign
    from bayesdoor.io import load_campaign

    if campaign_file is None:
        return load_demo_campaign("calibration")
    return load_campaign(campaign_file)


def fit_one(
    law: int | None,
    campaign_file: Path | None,
    seed: int,
    quick: bool,
    folder: Path,
    x0: dict[str, float] | None,
) -> float:
    """One fit written to ``folder``; returns the seconds it took.

    ``law=None``: the shared CMA-ES search with the law searched; else the law's NUTS fit
    started at ``x0``.
    """
    _configure_jax()
    from bayesdoor.door import ElevatorDoor
    from bayesdoor.inference import FitProblem, fit_campaign

    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = fit_campaign(
            ElevatorDoor(),
            _load(campaign_file),
            method="cmaes" if law is None else "nuts",
            problem=FitProblem(fixed=None if law is None else {"I": law}, x0=x0),
            seed=seed,
            progress=False,
            settings=settings_for("reference" if law is None else "law", quick),
        )
    result.save(folder, force=True)
    return time.perf_counter() - t0


def reusable(folder: Path, law: int | None, seed: int, quick: bool, x0) -> Any:
    """The fit saved in ``folder`` when it was made with these settings, else ``None``."""
    from bayesdoor.inference import FitResult

    if not (folder / "fit.json").is_file():
        return None
    r = FitResult.load(folder)
    settings = settings_for("reference" if law is None else "law", quick)
    same = r.settings == settings and r.seed == seed
    if law is not None:
        # the parent writes the start beside a finished fit: FitResult does not record x0
        path = folder / "start.json"
        started = json.loads(path.read_text()) if path.is_file() else None
        same = same and r.held == {"I": law} and started == [x0[n] for n in r.names]
    return r if same else None


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes (FitSettings.quick)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--campaign", type=Path, help="a campaign file (default: the cached demo campaign)"
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=OUT,
        help=f"the Markdown file to write (default {OUT.relative_to(ROOT)}; a .json beside it)",
    )
    parser.add_argument(
        "--workers",
        type=int,
        default=None,
        help="fits run at the same time (default: min(9, CPU cores))",
    )
    parser.add_argument(
        "--work",
        type=Path,
        help="folder for the fits; fits already there with the same settings are reused "
        "(default: a temporary folder, nothing reused)",
    )
    parser.add_argument(
        "--laws", type=int, nargs="+", default=list(LAWS), help="the laws to fit (default all)"
    )
    args = parser.parse_args()
    workers = args.workers or min(9, os.cpu_count() or 1)
    if workers < 1:
        parser.error(f"--workers={workers} must be at least 1")
    bad = sorted(set(args.laws) - set(LAWS))
    if bad:
        parser.error(f"--laws {bad}: contact laws are numbered 1 to 9")
    laws = sorted(set(args.laws))
    # read by XLA when a worker starts its backend: one compute thread per worker process
    os.environ["XLA_FLAGS"] = (
        os.environ.get("XLA_FLAGS", "")
        + " --xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
    ).strip()
    _configure_jax()

    from _cases import code_version, write_results

    from bayesdoor.door import ElevatorDoor
    from bayesdoor.inference import FitResult
    from bayesdoor.report import ablation_table

    door = ElevatorDoor()
    c_r_bounds = next((p.lower, p.upper) for p in door.parameters if p.name == "c_r")
    source = "the demo campaign" if args.campaign is None else args.campaign.name
    _load(args.campaign)  # generate (or read) the campaign once, before the workers need it
    started = time.perf_counter()
    seconds: dict[int, float] = {}
    results: dict[int, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(workers, mp_context=context) as pool:
            folder = work / "reference"
            reference = reusable(folder, None, args.seed, args.quick, None)
            if reference is None:
                reference_seconds = pool.submit(
                    fit_one, None, args.campaign, args.seed, args.quick, folder, None
                ).result()
                reference = FitResult.load(folder)
                print(
                    f"shared search: law {law_of(reference)}, J {reference.j:.4f}, "
                    f"{reference.cmaes.evaluations} evaluations, {reference_seconds:.0f} s",
                    file=sys.stderr,
                )
            starts = {
                law: warm_start(reference.point, law_of(reference), law, c_r_bounds) for law in laws
            }
            futures = {}
            # the reference law first: the pool runs fits in the order they are submitted
            for law in sorted(laws, key=lambda k: k != law_of(reference)):
                folder = work / f"law_{law}"
                found = reusable(folder, law, args.seed, args.quick, starts[law])
                if found is not None:
                    results[law] = found
                    continue
                folder.mkdir(parents=True, exist_ok=True)
                (folder / "start.json").unlink(missing_ok=True)
                future = pool.submit(
                    fit_one, law, args.campaign, args.seed, args.quick, folder, starts[law]
                )
                futures[future] = law
            for future in as_completed(futures):
                law = futures[future]
                seconds[law] = future.result()
                folder = work / f"law_{law}"
                r = results[law] = FitResult.load(folder)
                (folder / "start.json").write_text(
                    json.dumps([starts[law][n] for n in r.names]) + "\n"
                )
                gates = r.diagnostics is not None and r.diagnostics.passed
                print(
                    f"law {law}: J {r.cmaes.f_best:.4f} at the optimum, {r.j:.4f} at the "
                    f"posterior mean, gates {'pass' if gates else 'FAIL'}, "
                    f"{seconds[law]:.0f} s",
                    file=sys.stderr,
                )
    results = dict(sorted(results.items()))
    rows, table = ablation_table(results, "I")
    table += search_table(starts, results, seconds)
    table += damping_table(results)
    elapsed = time.perf_counter() - started
    command = "scripts/contact_law_ablation.py" + (" --quick" if args.quick else "")
    if args.seed:
        command += f" --seed {args.seed}"
    if args.campaign is not None:
        command += f" --campaign {args.campaign}"
    if args.workers:
        command += f" --workers {args.workers}"
    if args.work is not None:
        command += f" --work {args.work}"
    if laws != list(LAWS):
        command += " --laws " + " ".join(map(str, laws))
    partial = [law for law in LAWS if law not in results]
    ref_xi = door_xi(reference)
    warm = settings_for("law", args.quick)
    header = (
        f"Command: `.venv/bin/python {command}` ({elapsed / 60:.1f} min, {workers} worker "
        f"processes on {os.cpu_count()} CPU cores, fits reused from --work not timed; "
        f"{'quick sizes, NOT converged' if args.quick else 'full sizes'}; "
        f"{len(reference.runs)} calibration runs of {source}; "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {code_version()})"
        + (f"\n\n**PARTIAL: laws {partial} not fitted.**" if partial else "")
        + "\n\n"
        f"How each law's optimum was found: one shared CMA-ES search with the law searched "
        f"({reference.cmaes.evaluations} evaluations, {reference.cmaes.restarts} restarts, "
        f"stop: {', '.join(reference.cmaes.stop)}) chose law {law_of(reference)} at J = "
        f"{reference.j:.4f} (c_r = {reference.point['c_r']:.4f}, xi = {ref_xi:.4f}); each "
        f"law then ran CMA-ES with the law fixed, started there with c_r moved to give the "
        f"same xi, step {warm.cmaes_sigma0} of each range, {warm.cmaes_max_evals} "
        "evaluations, no restart; then the surrogate and NUTS of `fit_campaign` "
        f"({warm.num_chains} chains, {warm.num_warmup} warm-up + {warm.num_samples} draws "
        "each). J in the first table is at the posterior mean.\n\n"
    )
    notes = [f"- law {law}: " + "; ".join(r.notes) for law, r in results.items() if r.notes]
    block = (
        header
        + table
        + ("\nNotes raised by the fits:\n\n" + "\n".join(notes) + "\n" if notes else "")
    )
    # the discussion after the block is kept
    write_results(args.out, "# Contact-law ablation\n\n" + block, echo=False)
    for row in rows:
        row["law"] = row["value"]  # the contact-law index I
        r = results[row["law"]]
        row["start"] = starts[row["law"]]
        row["j_optimum"] = r.cmaes.f_best
        row["optimum"] = dict(zip(r.names, r.cmaes.x_best.tolist(), strict=False))
        row["cmaes_evaluations"] = r.cmaes.evaluations
        row["diagnostics"] = r.diagnostics.to_json()
        row["notes"] = list(r.notes)
        row["timings"] = r.timings
    record = {
        "command": command,
        "partial": partial,
        "reference": {
            "law": law_of(reference),
            "point": reference.point,
            "j": reference.j,
            "xi": ref_xi,
            "evaluations": reference.cmaes.evaluations,
            "stop": list(reference.cmaes.stop),
        },
        "laws": rows,
    }
    args.out.with_suffix(".json").write_text(json.dumps(record, indent=1) + "\n")
    print(block)
    return 0


def law_of(fit) -> int:
    """The contact-law index a fit held (searched by CMA-ES or given)."""
    return int(fit.held["I"])


def door_xi(fit) -> float:
    """The hysteresis factor of a fit's law at its c_r."""
    from bayesdoor.door.contact import get_law

    return float(get_law(law_of(fit)).hysteresis_factor(jnp.asarray(fit.point["c_r"])))


if __name__ == "__main__":
    raise SystemExit(main())
