"""Contact-law ablation: one posterior per law on the demo campaign's calibration runs.

For each of the nine contact laws: CMA-ES on the paper's J with the law fixed, then a NUTS
posterior on the surrogate (``bayesdoor.inference.fit_campaign``), the fitted J, posterior
means and sds, PSIS-LOO ELPD with its SE and stacking weights (``arviz.compare``). Writes
``results/contact_law_ablation.md`` (the table between the markers is regenerated; the
discussion around it is kept) and ``results/contact_law_ablation.json``.

Usage::

    .venv/bin/python scripts/contact_law_ablation.py [--quick] [--seed N]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import jax

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


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes (FitSettings.quick)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--campaign", type=Path, help="a campaign file (default: the cached demo campaign)"
    )
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)
    jax.config.update("jax_compilation_cache_dir", str(ROOT / ".jax_cache"))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)

    from bayesdoor.datasets import load_demo_campaign
    from bayesdoor.inference import fit_campaign
    from bayesdoor.io import load_campaign
    from bayesdoor.report import ablation_table
    from bayesdoor.systems import ElevatorDoor

    door = ElevatorDoor()
    if args.campaign is None:
        campaign = load_demo_campaign("calibration")
        source = "the demo campaign"
    else:
        campaign = load_campaign(args.campaign)
        source = f"{args.campaign.name}"
    law_spec = next(p for p in door.parameters if p.integer)
    results = {}
    started = time.perf_counter()
    for law in range(int(law_spec.lower), int(law_spec.upper) + 1):
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            results[law] = fit_campaign(
                door, campaign, method="nuts", law=law, seed=args.seed, quick=args.quick
            )
        r = results[law]
        print(
            f"law {law}: J {r.j:.4f}, gates {'pass' if r.diagnostics.passed else 'FAIL'}, "
            f"{time.perf_counter() - t0:.0f} s",
            file=sys.stderr,
        )
    rows, table = ablation_table(results)
    table += damping_table(results)
    elapsed = time.perf_counter() - started
    command = "scripts/contact_law_ablation.py" + (" --quick" if args.quick else "")
    if args.seed:
        command += f" --seed {args.seed}"
    if args.campaign is not None:
        command += f" --campaign {args.campaign}"
    header = (
        f"Command: `.venv/bin/python {command}` ({elapsed / 60:.1f} min on the shared 2-core "
        f"machine; {'quick sizes, NOT converged' if args.quick else 'full sizes'}; "
        f"{len(results[1].runs)} calibration runs of {source})\n\n"
    )
    notes = [f"- law {law}: " + "; ".join(r.notes) for law, r in results.items() if r.notes]
    block = (
        header
        + table
        + ("\nNotes raised by the fits:\n\n" + "\n".join(notes) + "\n" if notes else "")
    )
    text = (
        OUT.read_text()
        if OUT.exists()
        else "# Contact-law ablation\n\n" + BEGIN + "\n" + END + "\n"
    )
    before, _, rest = text.partition(BEGIN)
    _, _, after = rest.partition(END)
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(before + BEGIN + "\n" + block + END + after)
    OUT.with_suffix(".json").write_text(json.dumps(rows, indent=1) + "\n")
    print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
