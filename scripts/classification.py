"""Accuracy and calibration on the demo campaign's 300 test runs -> results/classification.md.

For each training-data source (the paper's Gaussian scatter around the CMA-ES optimum,
posterior draws, posterior draws plus the measured discrepancy) and each seed, the main job
(``bayesdoor.pipeline.run_job``) simulates training data, trains and calibrates the ensemble on
simulations only, and classifies the test runs. One fit on the 10 calibration runs (seed 0)
serves every job: its stage folder is copied into each job folder, where the stage's
configuration hash makes the job reuse it. The test runs are used for nothing but the final
scores.

The out-of-distribution flag of every job is also applied to probes that no training state
explains: the test runs 3 times louder, with the two sensors' cables swapped, with a 50 Hz
mains line added, and (``--rig-probes N``) N healthy runs recorded by the virtual rig with
an extra frame mode (``FrameMode.from_seed(0..N-1)``), at the campaign's speeds in turn.

With ``--jobs N`` the jobs after the first (which makes the shared fit) run in N worker
processes; the tables are the same. ``--tables-only`` runs nothing: it rewrites the results
file from ``OUT/rows.json`` of a finished or interrupted study (after a change of wording).

Usage::

    .venv/bin/python scripts/classification.py [--seeds 0 1 2] [--out out/classification]
        [--runs-per-state 600] [--method nuts] [--jobs 1] [--rig-probes 12] [--tables-only]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import platform
import shutil
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any, cast

import numpy as np
from _cases import code_version, write_results

ROOT = Path(__file__).resolve().parent.parent
PAPER_ACCURACY = 0.923
STATES = ("healthy", "D1", "D2")
LABELS = {
    "gaussian": "Gaussian scatter around the CMA-ES optimum (paper's baseline, 5 %)",
    "posterior": "posterior draws",
    "posterior+model_error": "posterior draws + the measured discrepancy (the default)",
}
#: the channel each channel reads when the two sensors' cables are swapped
SENSOR_SWAP = {"A1X": "A2X", "A1Z": "A2Z", "A2X": "A1X", "A2Z": "A1Z"}


def _spec():
    """The classifier input the job gives the door (the same for every source)."""
    from bayesdoor.door import ElevatorDoor
    from bayesdoor.features import CNNInputSpec

    declared = ElevatorDoor().features
    return CNNInputSpec(fmax=declared.classifier_fmax, nperseg=declared.classifier_nperseg)


def _probes_file() -> str:
    """The probes' cache, named by the classifier input (a changed input makes new ones)."""
    spec = _spec()
    return f"probes-{spec.fmax:g}hz-{spec.nperseg}.npz"


#: the OOD probes, in the order of the table (the measured test runs first)
PROBES = {
    "test": "measured test runs (known states)",
    "louder_3x": "test runs, every amplitude x 3",
    "sensors_swapped": "test runs, sensors A1 and A2 swapped",
    "hum_0.03": "test runs + 50 Hz line of 0.03 m/s^2 (the rig's strongest mains_hum)",
    "hum_0.3": "test runs + 50 Hz line of 0.3 m/s^2",
    "frame_mode": "rig runs (healthy) with an extra frame mode",
}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "classification")
    parser.add_argument("--runs-per-state", type=int, default=600)
    parser.add_argument("--method", default="nuts")
    parser.add_argument(
        "--fit-evals", type=int, default=None, help="CMA-ES evaluations (default: the fit's)"
    )
    parser.add_argument(
        "--fit-motion", type=float, default=None, help="seconds of motion per calibration run"
    )
    parser.add_argument(
        "--sources", nargs="+", default=["gaussian", "posterior", "posterior+model_error"]
    )
    parser.add_argument(
        "--campaign", type=Path, default=None, help="a campaign file instead of the demo's"
    )
    parser.add_argument("--results", type=Path, default=ROOT / "results" / "classification.md")
    parser.add_argument(
        "--jobs", type=int, default=1, help="worker processes for the jobs after the first"
    )
    parser.add_argument(
        "--rig-probes", type=int, default=12, help="rig runs with a frame mode (OOD probes)"
    )
    parser.add_argument(
        "--tables-only",
        action="store_true",
        help="run nothing: rewrite the results file from OUT/rows.json",
    )
    args = parser.parse_args(argv)
    if args.jobs < 1:
        parser.error(f"--jobs must be at least 1, got {args.jobs}")

    from bayesdoor import configure_jax

    configure_jax()
    from bayesdoor.pipeline import FitSummary

    if args.tables_only:
        rewrite_tables(args)
        return
    campaign, campaign_name = _campaign(args.campaign)
    start = time.perf_counter()

    def line(text: str) -> None:
        print(f"[{time.perf_counter() - start:7.1f} s] {text}", flush=True)

    args.out.mkdir(parents=True, exist_ok=True)
    probes_file = args.out / _probes_file()
    if not probes_file.exists():
        line(f"OOD probes ({args.rig_probes} rig runs with a frame mode)")
        probes = ood_probes(campaign, args.rig_probes, _spec())
        np.savez(probes_file, **probes)
    settings = {k: getattr(args, k) for k in _JOB_SETTINGS}
    jobs = [(seed, source) for seed in args.seeds for source in args.sources]
    shared_fit = args.out / "shared-fit"
    rows = []

    def finished(row: dict) -> None:
        rows.append(row)
        rows.sort(key=lambda r: (args.seeds.index(r["seed"]), args.sources.index(r["source"])))
        line(
            f"  {row['source']}-seed{row['seed']}: accuracy {row['accuracy']:.4f}, "
            f"ECE {row['ece']:.4f}, NLL {row['nll']:.3f}, Brier {row['brier']:.3f}, "
            f"OOD {row['ood']} of {row['runs']}"
        )
        (args.out / "rows.json").write_text(json.dumps(rows, indent=1))
        # after every job, so that an interrupted study still leaves its table
        write_markdown(
            args,
            rows,
            FitSummary.load(shared_fit),
            _fit_settings(settings),
            time.perf_counter() - start,
            campaign_name,
        )

    if not shared_fit.is_dir():
        seed, source = jobs.pop(0)
        line(f"job {source}-seed{seed} (makes the shared fit)")
        finished(run_one(settings, seed, source))
    if args.jobs == 1:
        for seed, source in jobs:
            line(f"job {source}-seed{seed}")
            finished(run_one(settings, seed, source))
        return
    line(f"{len(jobs)} jobs in {args.jobs} worker processes")
    context = multiprocessing.get_context("spawn")  # JAX does not survive a fork
    with ProcessPoolExecutor(max_workers=args.jobs, mp_context=context) as pool:
        futures = [pool.submit(run_one, settings, seed, source) for seed, source in jobs]
        for future in as_completed(futures):
            finished(future.result())


#: the command-line settings a job needs (passed to the worker processes)
_JOB_SETTINGS = ("out", "runs_per_state", "method", "fit_evals", "fit_motion", "campaign")


def rewrite_tables(args) -> None:
    """The results file of the jobs recorded in ``OUT/rows.json`` (``--tables-only``)."""
    from bayesdoor.door.datasets import demo_paths
    from bayesdoor.pipeline import FitSummary

    rows_file = args.out / "rows.json"
    if not rows_file.is_file() or not (args.out / "shared-fit").is_dir():
        raise SystemExit(
            f"--tables-only needs {rows_file} and {args.out / 'shared-fit'}: run the study "
            "into --out first"
        )
    rows = json.loads(rows_file.read_text())
    write_markdown(
        args,
        rows,
        FitSummary.load(args.out / "shared-fit"),
        _fit_settings({k: getattr(args, k) for k in _JOB_SETTINGS}),
        None,
        demo_paths()[0].name if args.campaign is None else args.campaign.name,
    )


def _campaign(path: Path | None):
    from bayesdoor.door.datasets import demo_paths, load_demo_campaign
    from bayesdoor.io import load_campaign

    if path is None:
        return load_demo_campaign(), demo_paths()[0].name
    return load_campaign(path), path.name


def _fit_settings(settings: dict):
    from bayesdoor.inference import FitSettings

    changes = {"cmaes_max_evals": settings["fit_evals"], "max_motion_s": settings["fit_motion"]}
    return FitSettings(**{k: v for k, v in changes.items() if v is not None})


def run_one(settings: dict, seed: int, source: str) -> dict:
    """One job (in this process or a worker): run it, score it, apply its flag to the probes."""
    from bayesdoor import configure_jax

    configure_jax()
    import jax.numpy as jnp

    from bayesdoor.classify import load_ensemble, predict
    from bayesdoor.door import ElevatorDoor
    from bayesdoor.pipeline import JobConfig, Sizes, Source, run_job

    out = settings["out"]
    campaign, _ = _campaign(settings["campaign"])
    folder = out / f"{source}-seed{seed}"
    shared_fit = out / "shared-fit"
    if shared_fit.is_dir() and not (folder / "fit").exists():
        folder.mkdir(parents=True, exist_ok=True)
        shutil.copytree(shared_fit, folder / "fit")

    def stage_line(text: str) -> None:
        print(f"  {folder.name}: {text}", flush=True)

    result = run_job(
        ElevatorDoor(),
        campaign,
        folder,
        JobConfig(
            seed=seed,
            fit_seed=0,
            source=cast(Source, source),
            method=settings["method"],
            sizes=Sizes(runs_per_state=settings["runs_per_state"]),
            fit_options={"settings": _fit_settings(settings)},
            html=False,
        ),
        progress=False,
        report=stage_line,
        overwrite=True,
    )
    if not shared_fit.is_dir():
        shutil.copytree(folder / "fit", shared_fit)
    m = result.classification["metrics"]
    training = json.loads((folder / "train" / "training.json").read_text())
    ensemble = load_ensemble(folder / "train" / "ensemble.eqx")
    with np.load(out / _probes_file()) as probes:
        flagged = {
            name: float(np.mean(np.asarray(predict(ensemble, jnp.asarray(probes[name])).ood)))
            for name in probes.files
        }
    return {
        "source": source,
        "seed": seed,
        **{k: m[k] for k in ("accuracy", "ece", "ece_mass", "nll", "brier")},
        "ood": m["ood_runs"],
        "runs": m["runs"],
        "ood_rates": flagged,
        "ood_model_error_draws": training.get("ood_model_error_draws", 0),
        "confusion": m["confusion"],
        "temperature": training["temperature"],
        "val_accuracy": training["validation"]["calibrated"]["accuracy"],
        "val_ece": training["validation"]["calibrated"]["ece"],
    }


def ood_probes(campaign, rig_runs: int, spec, seed: int = 0) -> dict[str, Any]:
    """Classifier features of the test runs and of inputs no training state explains."""
    import jax

    from bayesdoor.datagen import campaign_features
    from bayesdoor.door.rig import Effects, FrameMode, VirtualRig
    from bayesdoor.pipeline import runs_to_classify

    test = runs_to_classify(campaign)
    acc = test["acceleration"].transpose("run", "channel", "time")
    signals = np.asarray(acc.values, dtype=float)
    t = np.asarray(test["time"].values, dtype=float)
    channels = [str(c) for c in test["channel"].values]
    swap = [channels.index(SENSOR_SWAP[c]) for c in channels]
    rng = np.random.default_rng(seed)

    def features(x: np.ndarray) -> np.ndarray:
        return campaign_features(test.assign(acceleration=(acc.dims, x)), spec=spec)

    def hum(amplitude: float) -> np.ndarray:
        phase = rng.uniform(0.0, 2.0 * np.pi, (len(signals), 1, 1))
        return features(signals + amplitude * np.cos(2.0 * np.pi * 50.0 * t + phase))

    probes: dict[str, Any] = {
        "test": features(signals),
        "louder_3x": features(3.0 * signals),
        "sensors_swapped": features(signals[:, swap]),
        "hum_0.03": hum(0.03),
        "hum_0.3": hum(0.3),
    }
    if rig_runs:
        speeds = np.unique(np.asarray(campaign["v_max"].values, dtype=float))
        duration = float(t[-1] - t[0]) + 1.0 / float(campaign.attrs["sampling_rate_hz"])
        runs = [
            VirtualRig(effects=Effects(frame_mode=FrameMode.from_seed(i))).record(
                ["healthy"],
                [speeds[i % len(speeds)]],
                key=jax.random.key(1000 + i),
                duration=duration,
            )
            for i in range(rig_runs)
        ]
        probes["frame_mode"] = np.concatenate([campaign_features(r, spec=spec) for r in runs])
    return probes


def _mean_sd(values: list[float], digits: int = 3, scale: float = 1.0) -> str:
    v = scale * np.asarray(values, dtype=float)
    if v.size == 1:
        return f"{v[0]:.{digits}f}"
    return f"{v.mean():.{digits}f} ± {v.std(ddof=1):.{digits}f}"


def write_markdown(
    args, rows, fit, fit_settings, seconds: float | None, campaign_name: str
) -> None:
    """The results file; ``seconds=None`` for tables rewritten from ``rows.json``."""
    command = "python scripts/classification.py " + " ".join(sys.argv[1:])
    stamp = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    if seconds is None:
        made = (
            f"Tables rewritten from `{args.out}/rows.json` by `{command.strip()}` ({stamp}; "
            f"{len(rows)} job(s) recorded of {len(args.seeds) * len(args.sources)}; written by "
            f"{code_version()})."
        )
    else:
        made = (
            f"Made by `{command.strip()}` ({stamp}, {seconds / 60:.0f} min on a shared "
            f"{platform.machine()} machine; {len(rows)} job(s) done of "
            f"{len(args.seeds) * len(args.sources)}; {code_version()})."
        )
    lines = [
        "# Classification of the demo campaign's test runs",
        "",
        made,
        "",
        f"Data: the embedded demo campaign (`{campaign_name}`), recorded by the virtual rig: "
        "10 healthy calibration runs and 300 test runs (100 healthy, 100 D1, 100 D2 at 0.3, "
        "0.4 and 0.5 m/s). The classifier is trained on simulations of the reduced door model "
        f"only ({args.runs_per_state} runs per state, 70/30 train/validation split; 10 members, "
        "80 epochs, batch 100); its temperature is fitted on the simulated validation split, "
        "its OOD covariance and threshold on simulated runs plus model-error draws (see the "
        "OOD section). The test runs are used for the scores below and nothing else.",
        "",
        f"Fit settings: `{fit_settings}`.",
        "",
        "## Scores on the 300 test runs (mean ± sd over seeds)",
        "",
        "| training data | accuracy | ECE (15 bins) | ECE (equal mass) | NLL | Brier | "
        "flagged OOD | simulated validation accuracy |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for source in args.sources:
        sel = [r for r in rows if r["source"] == source]
        if not sel:
            continue
        lines.append(
            f"| {LABELS[source]} | {_mean_sd([r['accuracy'] for r in sel], 1, 100)} % | "
            f"{_mean_sd([r['ece'] for r in sel])} | {_mean_sd([r['ece_mass'] for r in sel])} | "
            f"{_mean_sd([r['nll'] for r in sel])} | {_mean_sd([r['brier'] for r in sel])} | "
            f"{_mean_sd([r['ood'] for r in sel], 1)} | "
            f"{_mean_sd([r['val_accuracy'] for r in sel], 1, 100)} % |"
        )
    lines += [
        "",
        f"The paper reports {100 * PAPER_ACCURACY:.1f} % on its door (Gaussian scatter, "
        "measured test data). The targets for the posterior variant: accuracy >= 95 % "
        "and ECE <= 0.05.",
        "",
        "## Every job",
        "",
        "| training data | seed | accuracy | ECE | NLL | Brier | OOD | temperature | "
        "confusion (rows: true healthy, D1, D2) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['source']} | {r['seed']} | {100 * r['accuracy']:.1f} % | {r['ece']:.3f} | "
            f"{r['nll']:.3f} | {r['brier']:.3f} | {r['ood']} | {r['temperature']:.2f} | "
            f"{r['confusion']} |"
        )
    lines += ["", *_ood_section(args.sources, rows)]
    j = "-" if fit.j is None else f"{fit.j:.4g}"
    lines += [
        "",
        f"## The fit they share ({fit.method}, seed 0, J = {j})",
        "",
        "| parameter | CMA-ES optimum | posterior mean | sd | 90 % interval |",
        "|---|---|---|---|---|",
    ]
    for row in fit.table():
        interval = "-" if "q05" not in row else f"{row['q05']:.4g} to {row['q95']:.4g}"
        mean = "-" if "mean" not in row else f"{row['mean']:.4g}"
        sd = "-" if "sd" not in row else f"{row['sd']:.3g}"
        lines.append(f"| {row['parameter']} | {row['point']:.4g} | {mean} | {sd} | {interval} |")
    if fit.sigma_model is not None:
        sigma = ", ".join(f"{v:.3f}" for v in np.mean(fit.sigma_model, axis=0))
        lines += [
            "",
            "Model-error scale per channel (log10 decades, in the campaign's channel order; "
            "posterior mean of the root mean square over the operating points of the "
            f"discrepancy scale the likelihood fits per operating point and channel): {sigma}. "
            "The `posterior+model_error` source adds one offset per run and channel, drawn "
            "with a posterior draw of this scale, to the simulated features.",
        ]
    lines += ["", *_comparison(args.sources, rows), ""]
    write_results(args.results, "\n".join(lines), echo=False)


def _ood_section(sources, rows) -> list[str]:
    """Flag rates of the OOD detector on the test runs and on the probes, per source."""
    used = [src for src in sources if any(r["source"] == src for r in rows)]
    draws = sorted({r["ood_model_error_draws"] for r in rows})
    out = [
        "## The out-of-distribution flag",
        "",
        "Share of runs flagged (mean ± sd over seeds). The detector (docs/classification.md) is "
        "the Mahalanobis distance to the nearest simulated class mean. Its reference is a "
        "measurement of a simulated state: model-error draws (per job: "
        f"{', '.join(map(str, draws))}), each the residual of one healthy calibration run about "
        "the simulated healthy mean at its speed plus independent per-feature scatter (the Welch "
        "scatter of the shortest window and the fit's mean squared model-error scale); half of "
        "the draws enter the covariance (with the simulated within-class scatter), the other "
        "half are added to the simulated validation runs, whose 99th percentile is the "
        "threshold (about 1 % of in-distribution inputs flagged by design). The test runs are "
        "not used; the calibration runs are the fit's.",
        "",
        "| input | " + " | ".join(LABELS[src] for src in used) + " |",
        "|---|" + "---|" * len(used),
    ]
    for name, label in PROBES.items():
        cells = []
        for src in used:
            rates = [
                r["ood_rates"][name] for r in rows if r["source"] == src and name in r["ood_rates"]
            ]
            cells.append(_mean_sd(rates, 1, 100) + " %" if rates else "-")
        out.append(f"| {label} | " + " | ".join(cells) + " |")
    return out


def _comparison(sources, rows) -> list[str]:
    """The comparison with the paper and the targets, in words, from the numbers."""
    out = ["## Against the paper and the targets", ""]
    for source in sources:
        sel = [r for r in rows if r["source"] == source]
        if not sel:
            continue
        acc = float(np.mean([r["accuracy"] for r in sel]))
        ece = float(np.mean([r["ece"] for r in sel]))
        verdict = "above" if acc > PAPER_ACCURACY else "below"
        text = (
            f"- {LABELS[source]}: mean accuracy {100 * acc:.1f} %, {verdict} the paper's "
            f"{100 * PAPER_ACCURACY:.1f} %; mean ECE {ece:.3f}."
        )
        confusion = np.mean([r["confusion"] for r in sel], axis=0)
        errors = confusion - np.diag(np.diag(confusion))
        if errors.max() > 0:
            t, p = np.unravel_index(np.argmax(errors), errors.shape)
            text += (
                f" Most frequent error: true {STATES[t]} predicted {STATES[p]} "
                f"({errors[t, p]:.1f} of 100 runs per job)."
            )
        if source == "posterior":
            met = [
                f"accuracy >= 95 %: {'met' if acc >= 0.95 else 'NOT met'}",
                f"ECE <= 0.05: {'met' if ece <= 0.05 else 'NOT met'}",
            ]
            text += " Targets: " + "; ".join(met) + "."
        out.append(text)
    return out


if __name__ == "__main__":
    main()
