"""Contact-law ablation: one posterior per law on the demo campaign's calibration runs.

For each of the nine contact laws: CMA-ES on the paper's J with the law fixed, then a NUTS
posterior on the surrogate (``bayesdoor.inference.fit_campaign``), the fitted J, posterior
means and sds, PSIS-LOO ELPD with its SE and stacking weights (``arviz.compare``). Writes
``results/contact_law_ablation.md`` (the table between the markers is regenerated; the
discussion around it is kept) and ``results/contact_law_ablation.json``.

The nine fits are independent, so they run in a pool of ``--workers`` processes (default: one
per law, at most one per CPU core), each with XLA on one thread (a vmapped diffrax solve on
the CPU gains little from more), sharing the project's compilation cache; each worker writes
its fit to a temporary folder (``FitResult.save``) and the parent reads them back. On the
shared 2-core machine use ``--quick``; the full sizes are meant for a 16-core machine, where
the nine fits run side by side.

Usage::

    .venv/bin/python scripts/contact_law_ablation.py [--quick] [--seed N] [--workers W]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import sys
import tempfile
import time
import warnings
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "results" / "contact_law_ablation.md"
BEGIN, END = "<!-- table: begin -->", "<!-- table: end -->"


def damping_table(results) -> str:
    """Per law: the posterior of c_r and of the hysteresis factor xi(c_r) it implies.

    In persistent rolling contact the latched approach velocity sits at its floor, so the
    damping is xi(c_r) K d^n / floor: what the data can fix is xi, not which law produced it.
    """
    import numpy as np

    from bayesdoor.contact import LAW_NAMES, get_law

    lines = [
        "",
        "| law | name | c_r mean (sd) | xi(c_r) mean (sd) | xi range over c_r in [0.6, 0.95] |",
        "|---|---|---|---|---|",
    ]
    for law, r in results.items():
        c_r = r.posterior_draws()["c_r"]
        xi = np.asarray(get_law(law).hysteresis_factor(c_r))
        ends = np.asarray(get_law(law).hysteresis_factor(np.array([0.95, 0.6])))
        lines.append(
            f"| {law} | {LAW_NAMES[law - 1]} | {c_r.mean():.3f} ({c_r.std():.3f}) | "
            f"{xi.mean():.3f} ({xi.std():.3f}) | {ends[0]:.3f} to {ends[1]:.3f} |"
        )
    return "\n".join(lines) + "\n"


def _configure_jax() -> None:
    import jax

    jax.config.update("jax_enable_x64", True)
    jax.config.update("jax_compilation_cache_dir", str(ROOT / ".jax_cache"))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)


def _load(campaign_file: Path | None):
    from bayesdoor.datasets import load_demo_campaign
    from bayesdoor.io import load_campaign

    if campaign_file is None:
        return load_demo_campaign("calibration")
    return load_campaign(campaign_file)


def fit_one(law: int, campaign_file: Path | None, seed: int, quick: bool, folder: Path) -> float:
    """One law's NUTS fit, written to ``folder``; returns the seconds it took."""
    _configure_jax()
    from bayesdoor.inference import fit_campaign
    from bayesdoor.systems import ElevatorDoor

    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = fit_campaign(
            ElevatorDoor(),
            _load(campaign_file),
            method="nuts",
            law=law,
            seed=seed,
            quick=quick,
            progress=False,
        )
    result.save(folder, force=True)
    return time.perf_counter() - t0


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
    args = parser.parse_args()
    workers = args.workers or min(9, os.cpu_count() or 1)
    if workers < 1:
        parser.error(f"--workers={workers} must be at least 1")
    # read by XLA when a worker starts its backend: one compute thread per worker process
    os.environ["XLA_FLAGS"] = (
        os.environ.get("XLA_FLAGS", "")
        + " --xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
    ).strip()
    _configure_jax()

    from bayesdoor.inference import FitResult
    from bayesdoor.report import ablation_table
    from bayesdoor.systems import ElevatorDoor

    door = ElevatorDoor()
    source = "the demo campaign" if args.campaign is None else args.campaign.name
    _load(args.campaign)  # generate (or read) the campaign once, before the workers need it
    law_spec = next(p for p in door.parameters if p.integer)
    laws = range(int(law_spec.lower), int(law_spec.upper) + 1)
    results = {}
    started = time.perf_counter()
    with (
        tempfile.TemporaryDirectory() as tmp,
        ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool,
    ):
        folders = {law: Path(tmp) / f"law_{law}" for law in laws}
        futures = {
            pool.submit(fit_one, law, args.campaign, args.seed, args.quick, folders[law]): law
            for law in laws
        }
        for future in as_completed(futures):
            law = futures[future]
            seconds = future.result()
            r = results[law] = FitResult.load(folders[law])
            print(
                f"law {law}: J {r.j:.4f}, gates {'pass' if r.diagnostics.passed else 'FAIL'}, "
                f"{seconds:.0f} s",
                file=sys.stderr,
            )
    results = dict(sorted(results.items()))
    rows, table = ablation_table(results)
    table += damping_table(results)
    elapsed = time.perf_counter() - started
    command = "scripts/contact_law_ablation.py" + (" --quick" if args.quick else "")
    if args.seed:
        command += f" --seed {args.seed}"
    if args.campaign is not None:
        command += f" --campaign {args.campaign}"
    if args.workers:
        command += f" --workers {args.workers}"
    header = (
        f"Command: `.venv/bin/python {command}` ({elapsed / 60:.1f} min, {workers} worker "
        f"processes on {os.cpu_count()} CPU cores; "
        f"{'quick sizes, NOT converged' if args.quick else 'full sizes'}; "
        f"{len(results[1].runs)} calibration runs of {source})\n\n"
    )
    notes = [f"- law {law}: " + "; ".join(r.notes) for law, r in results.items() if r.notes]
    block = (
        header
        + table
        + ("\nNotes raised by the fits:\n\n" + "\n".join(notes) + "\n" if notes else "")
    )
    out = args.out
    text = (
        out.read_text()
        if out.exists()
        else "# Contact-law ablation\n\n" + BEGIN + "\n" + END + "\n"
    )
    before, _, rest = text.partition(BEGIN)
    _, _, after = rest.partition(END)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(before + BEGIN + "\n" + block + END + after)
    out.with_suffix(".json").write_text(json.dumps(rows, indent=1) + "\n")
    print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
