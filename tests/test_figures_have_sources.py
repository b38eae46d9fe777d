"""The figures of README.md's headline table and of docs/validation.md are those of the results
files they cite, and every results file names the command, the date and the commit that made it.

Each figure is read from its results file (a row of a table the file's script writes, or a
sentence of its notes), formatted as the page prints it, and looked up in the page's paragraph
or table row that links that file: a results file made again with other figures, or a page
edited by hand, fails here until the two agree. The speed figures are held to
results/performance.json by tests/test_performance_figures.py.
"""

import json
import re
from collections.abc import Callable, Iterable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "results"


def _results(name: str) -> str:
    return (RESULTS / name).read_text(encoding="utf-8")


def _rows(name: str) -> list[list[str]]:
    """The cells of every Markdown table row of a results file."""
    return [
        [cell.strip() for cell in line.strip()[1:-1].split("|")]
        for line in _results(name).splitlines()
        if line.startswith("| ") and not line.startswith("|---")
    ]


def _row(name: str, *first: str) -> list[str]:
    """The first table row of ``name`` whose leading cells are ``first``."""
    for cells in _rows(name):
        if tuple(cells[: len(first)]) == first:
            return cells
    raise AssertionError(f"results/{name} has no table row starting {' | '.join(first)!r}")


def _find(name: str, pattern: str) -> re.Match:
    match = re.search(pattern, " ".join(_results(name).split()))
    assert match, f"results/{name} no longer says {pattern!r}"
    return match


def _lead(cell: str) -> float:
    """The first number of a cell: '0.917 (worst 0.883, ...)', '99 of 190: 0.980', '96.7 %'."""
    return float(re.match(r"[-+]?[\d.]+", cell).group(0))


def _worst(cell: str) -> float:
    return float(re.search(r"worst ([\d.]+)", cell).group(1))


def _best(cell: str) -> float:
    return float(re.search(r"best ([\d.]+)", cell).group(1))


def _span(values: Iterable[float], form: str) -> str:
    """'a' when the values print alike, else 'lowest-highest', each printed with ``form``."""
    low, high = (format(v, form) for v in (min(values), max(values)))
    return low if low == high else f"{low}-{high}"


def _pct(value: float, digits: int = 1) -> str:
    return f"{100 * value:.{digits}f}"


# --- the figures, per results file ------------------------------------------------------------


def _classification() -> dict[str, list[str]]:
    name = "classification.md"
    gauss = _row(name, "Gaussian scatter around the CMA-ES optimum (paper's baseline, 5 %)")
    post = _row(name, "posterior draws")
    default = _row(name, "posterior draws + the measured discrepancy (the default)")
    paper = _find(name, r"The paper reports ([\d.]+ %)").group(1)

    def mean(cell: str) -> str:
        return cell.split(" ±")[0]

    flagged = {
        what: [_lead(cell) for cell in _row(name, what)[1:]]
        for what in (
            "measured test runs (known states)",
            "test runs, sensors A1 and A2 swapped",
            "test runs + 50 Hz line of 0.03 m/s^2 (the rig's strongest mains_hum)",
            "test runs + 50 Hz line of 0.3 m/s^2",
            "rig runs (healthy) with an extra frame mode",
        )
    }
    measured = flagged["measured test runs (known states)"]
    return {
        "README.md": [
            f"{post[1]} / {post[2]} (paper: {paper})",
            f"{gauss[1]} / {mean(gauss[2])}; {default[1]} / {mean(default[2])}",
        ],
        "docs/validation.md": [
            f"| `gaussian` (the paper's recipe) | {gauss[1]} | {gauss[2]} |",
            f"| `posterior` | {post[1]} | {post[2]} |",
            f"| `posterior+model_error` | {default[1]} | {default[2]} |",
            f"The paper reports {paper} on its door",
            f"{_span(measured[:2], '.1f')} % of the test runs are flagged "
            f"({measured[2]:.1f} % with the default source)",
            f"{_span(flagged['test runs, sensors A1 and A2 swapped'], '.0f')} % of the runs with "
            "two sensors swapped",
            f"{_span(flagged['test runs + 50 Hz line of 0.3 m/s^2'], '.0f')} % of runs with a "
            "loud 50 Hz line",
            f"{_span(flagged['rig runs (healthy) with an extra frame mode'], '.0f')} % of runs "
            "with a frame mode the model lacks",
            "a 50 Hz line at the rig's own level is flagged in "
            + _span(
                flagged["test runs + 50 Hz line of 0.03 m/s^2 (the rig's strongest mains_hum)"],
                ".1f",
            )
            + " % of runs",
        ],
    }


def _transfer() -> dict[str, list[str]]:
    name = "transfer.md"

    def cells(doors: str, source: str) -> tuple[float, float, float, float]:
        row = _row(name, doors, f"`{source}`")
        return _lead(row[3]), _worst(row[3]), _best(row[3]), _lead(row[4])

    default = [cells(doors, "posterior+model_error") for doors in ("development", "held out")]
    others = [
        cells(doors, source)
        for doors in ("development", "held out")
        for source in ("posterior", "gaussian")
    ]
    table = []
    for doors in ("development", "held out"):
        n = _row(name, doors, "`posterior+model_error`")[2]
        median, worst, _, ece = cells(doors, "posterior+model_error")
        table.append(
            f"| {n} {doors} | `posterior+model_error` | {_pct(median)} % ({_pct(worst)} %) "
            f"| {ece:.3f} |"
        )
        post, gauss = cells(doors, "posterior"), cells(doors, "gaussian")
        medians = _span([100 * post[0], 100 * gauss[0]], ".1f")
        worst = _span([100 * post[1], 100 * gauss[1]], ".1f")
        table.append(
            f"| {n} {doors} | `posterior`, `gaussian` | {medians} % ({worst} %) "
            f"| {post[3]:.2f}, {gauss[3]:.2f} |"
        )
    optimism = _find(name, r"optimistic by a median of ([\d.]+) points").group(1)
    door = _find(name, r"Door \d+ \(([\d.]+), expected ([\d.]+)\) is the one door below 90 %")
    cost = _find(name, r"median ([\d.]+) %, largest").group(1)
    return {
        "README.md": [
            f"default: median {_span([100 * d[0] for d in default], '.1f')} %, worst "
            f"{_pct(min(d[1] for d in default))} %, ECE {_span([d[3] for d in default], '.3f')}; "
            f"others {_pct(min(o[1] for o in others), 0)}-{_pct(max(o[2] for o in others), 0)} %"
        ],
        "docs/validation.md": [
            *table,
            f"optimistic by a median of {optimism} points",
            f"({_pct(float(door.group(1)))} %, expected {_pct(float(door.group(2)))} %)",
            f"a median {cost} % of the job's time",
        ],
    }


def _transfer_full_training() -> dict[str, list[str]]:
    name = "transfer_full_training.md"
    rows = [_row(name, doors, "`posterior+model_error`") for doors in ("development", "held out")]
    medians = [_pct(_lead(row[3])) for row in rows]
    worst = [100 * _worst(row[3]) for row in rows]
    ece = [_lead(row[4]) for row in rows]
    return {
        "README.md": [
            f"default: median {medians[0]} % / {medians[1]} % (development / held out), worst "
            f"{_span(worst, '.1f')} %, ECE {_span(ece, '.3f')}"
        ],
        "docs/validation.md": [
            f"a median of {medians[0]} % on the development doors and {medians[1]} % on the "
            "held-out ones",
            f"worst {_span(worst, '.1f')} % on both"
            if len(set(worst)) == 1
            else f"worst {worst[0]:.1f} % and {worst[1]:.1f} %",
            f"median ECE {ece[0]:.3f} and {ece[1]:.3f}",
        ],
    }


def _transfer_extended() -> dict[str, list[str]]:
    name = "transfer_extended.md"
    paired = _find(
        name,
        r"Paired change over the (\d+) doors with a named cause: accuracy ([-+\d., ]+); "
        r"ECE ([-+\d., ]+?)\. One test run of (\d+)",
    )
    per_run = int(paired.group(4))
    runs = [round(float(v) * per_run) for v in paired.group(2).split(",")]
    ece = [float(v) for v in paired.group(3).split(",")]
    return {
        "README.md": [
            f"cause named on {paired.group(1)}; accuracy {min(runs):+d} to {max(runs):+d} runs of "
            f"{per_run}, ECE {min(ece):+.3f} to {max(ece):+.3f}"
        ]
    }


def _cwru() -> dict[str, list[str]]:
    name = "cwru.md"
    jobs = [row for row in _rows(name) if row[0].startswith("nuts / posterior+model_error")][:3]
    assert len(jobs) == 3, "results/cwru.md: the summary's three NUTS seeds"
    cmaes = _row(name, "cmaes / gaussian")
    rule = _row(name, "physics rule (envelope lines)")
    balanced = [float(row[6]) for row in jobs]
    weighed = [_lead(row[3]) for row in jobs]
    alone = [float(re.search(r"\(([\d.]+)\)", row[3]).group(1)) for row in jobs]
    called = [int(row[8].split(" of ")[0]) for row in jobs]
    segments = int(jobs[0][8].split(" of ")[1].split(":")[0])
    right = [float(row[8].split(": ")[1]) for row in jobs]
    named = {row[7] for row in jobs}
    risk = _find(name, r"the job's selective risk \((\d+) %\)").group(1)
    return {
        "README.md": [
            f"record balanced accuracy {_span(balanced, '.2f')}, segment ECE "
            f"{_span(weighed, '.2f')} weighed against the envelope check (the ensemble alone "
            f"{_span(alone, '.2f')}); at a {risk} % selective risk {_span(called, 'd')} of "
            f"{segments} segments called, {_span([100 * r for r in right], '.0f')} % of them right",
            f"rule {float(rule[6]):.2f}",
        ],
        "docs/validation.md": [
            f"record balanced accuracy {_span(balanced, '.3f')}",
            f"segment ECE {_span(weighed, '.3f')} with the probabilities weighed against the "
            f"envelope check (the ensemble alone {_span(alone, '.3f')}",
            *(f"race records named: {n} with each seed" for n in named if len(named) == 1),
            f"At the {risk} % selective risk {_span(called, 'd')} of the {segments} segments are "
            f"called, {_span([100 * r for r in right], '.1f')} % of them right",
            "Misnamed records flagged: "
            + ", ".join(re.match(r"\d+ of \d+", row[10]).group(0) for row in jobs[:-1])
            + " and "
            + re.match(r"\d+ of \d+", jobs[-1][10]).group(0),
            f"record balanced accuracy {float(cmaes[6]):.3f}, segment ECE {_lead(cmaes[3]):.3f}",
            f"{float(rule[6]):.3f}, with {rule[7]} race records named",
        ],
    }


def _quick_job() -> tuple[str, str]:
    """The quick job's accuracy and ECE as results/performance.json holds them."""
    job = json.loads(_results("performance.json"))["job"]
    return f"{100 * job['accuracy']:.1f} %", f"ECE {job['ece']:.3f}"


def _performance() -> dict[str, list[str]]:
    name = "performance.md"
    job = json.loads(_results("performance.json"))["job"]
    accuracy, ece = _quick_job()
    h100 = float(_find(name, r"a float64 batch of 1024 takes \*\*([\d.]+) ms\*\* a run").group(1))
    full = _find(name, r"\*\*(\d+) s\*\* \(target (\d+) min; fit")
    target = re.search(r">= (\d+)x scipy", _results(name)).group(1)
    return {
        "README.md": [
            f"target {target}x); H100, batch 1024: {h100:.1f} ms",
            f"at the paper's sizes {full.group(1)} s (target {full.group(2)} min)",
        ],
        "docs/validation.md": [
            f"| the same on an H100 GPU, batch of 1024 | {h100:.2f} ms a run |",
            f"| {full.group(1)} s (99.0 %, ECE 0.0053) |",
            f"of it {job['compile_s']:.0f} s compiling, peak memory "
            f"{job['peak_memory_mb'] / 1024:.1f} GB, the posterior "
            + ("passing" if job["fit_steps"]["gates_passed"] else "failing")
            + f" its sampling gates; {accuracy}, {ece} |",
        ],
    }


_EFFECTS = {
    "frame_mode": ("frame mode", "frame mode"),
    "mains_hum": ("mains hum", "hum"),
    "rail_waviness": ("rail waviness", "rail"),
    "sensor_cross_axis": ("sensor cross-axis", "leak"),
    "wheel_eccentricity": ("wheel eccentricity", "wheel"),
}


def _diagnosis() -> dict[str, list[str]]:
    name = "diagnosis.md"
    rows = {effect: _row(name, effect) for effect in _EFFECTS}
    none = next(row for row in _rows(name) if row[0].startswith("none (false alarms: "))
    alarms = int(re.search(r"false alarms: (\d+)", none[0]).group(1))
    named = sum(int(row[2]) for row in rows.values())
    cases = sum(int(row[1]) for row in rows.values())
    return {
        "README.md": [
            f"{named} of {cases} named, "
            + (f"no false alarm in {none[1]}" if alarms == 0 else f"{alarms} false alarms")
        ],
        "docs/validation.md": [
            *(f"{_EFFECTS[e][0]} {row[2]} of {row[1]}" for e, row in rows.items()),
            f"{none[2]} of {none[1]} campaigns with nothing hidden answer `none`",
        ],
    }


def _diagnosis_full_size() -> dict[str, list[str]]:
    name = "diagnosis_full_size.md"
    cases = [row for row in _rows(name) if re.fullmatch(r"[a-z_]+ \d+", row[0])]
    counts = {}
    for effect in [*_EFFECTS, "none"]:
        own = [row for row in cases if row[0].rsplit(" ", 1)[0] == effect]
        counts[effect] = (sum(row[1] == effect for row in own), len(own))
    none = counts.pop("none")
    return {
        "README.md": [
            *(f"{_EFFECTS[e][1]} {k}/{n}" for e, (k, n) in counts.items()),
            f"no false alarm in {none[1]}"
            if none[0] == none[1]
            else f"{none[1] - none[0]} false alarms in {none[1]}",
        ],
        "docs/validation.md": [
            *(f"{_EFFECTS[e][0]} {k} of {n}" for e, (k, n) in counts.items()),
            f"{none[0]} of {none[1]} campaigns with nothing hidden answer `none`",
        ],
    }


def _diagnosis_limits() -> dict[str, list[str]]:
    name = "diagnosis_limits.md"

    def named(cause: str, factor: str) -> tuple[int, int]:
        k, n = _row(name, cause, factor)[3].split(" of ")
        return int(k), int(n)

    def limit(cause: str) -> str:
        return _row(name, cause)[3].removesuffix(" -")

    (w05, n), (w15, _) = named("wheel_eccentricity", "0.5"), named("wheel_eccentricity", "1.5")
    (h05, _), (h15, _) = named("mains_hum", "0.5"), named("mains_hum", "1.5")
    (r05, _), (r15, _) = named("rail_waviness", "0.5"), named("rail_waviness", "1.5")
    (s05, _), (s15, _) = named("sensor_cross_axis", "0.5"), named("sensor_cross_axis", "1.5")
    return {
        "README.md": [
            f"wheel {w15}/{n} / {w05}/{n}, hum {h15}/{n} / {h05}/{n}; rail {r15}/{n}, leak "
            f"{s15}/{n} at 1.5x"
        ],
        "docs/validation.md": [
            f"wheel run-out (limit {limit('wheel_eccentricity')}) named {w05} and {w15} of {n}",
            f"mains hum ({limit('mains_hum')}) {h05} and {h15} of {n}",
            f"rail waviness ({limit('rail_waviness')}) {r05} and {r15} of {n}",
            f"cross-axis leak, sized on the measured signals ({limit('sensor_cross_axis')}), "
            f"{s05} and {s15} of {n}",
        ],
    }


def _diagnosis_limits_hum() -> dict[str, list[str]]:
    misses = {
        re.search(r"at run \d+: ([\d.]+)", row[5]).group(1)
        for row in _rows("diagnosis_limits_hum.md")
        if row[:2] == ["mains_hum", "1.5"] and len(row) == 7 and row[3] == "no"
    }
    count = sum(
        row[3] == "no"
        for row in _rows("diagnosis_limits_hum.md")
        if row[:2] == ["mains_hum", "1.5"] and len(row) == 7
    )
    assert len(misses) == 1, "the hum's misses lose most on one run"
    return {
        "docs/validation.md": [
            f"the hum's {_NUMBERS[count]} misses come from one held-out run at {misses.pop()} m/s"
        ]
    }


def _hum_interference() -> dict[str, list[str]]:
    speed = _find("hum_interference.md", r"At ([\d.]+) m/s \(run \d+\) the door itself has a line")
    return {
        "docs/validation.md": [
            f"run at {speed.group(1)} m/s where the door's own line and the hum's cancel at the "
            "rig's chance phase"
        ]
    }


def _inference() -> dict[str, list[str]]:
    name = "inference.md"
    runs = _find(name, r"## The reduced model's best values on (\d+) runs").group(1)
    k, mf = (_row(name, parameter)[3] for parameter in ("K", "MF"))
    return {
        "README.md": [
            f"K and MF sit at the reduced model's own best point, {k} and {mf} on {runs} runs"
        ]
    }


def _diagnosis_plan_wheel() -> dict[str, list[str]]:
    name = "diagnosis_plan_wheel.md"
    row = _row(name, "wheel_eccentricity", "15 um")
    speed = _find(name, rf"{row[2]} runs at ([\d.]+) \(").group(1)
    interval = re.search(r"\(([\d.]+-[\d.]+)\)", row[4]).group(1)
    return {
        "docs/validation.md": [
            f"{row[2]} runs at {speed} m/s, planned probability {row[5]}; named in {row[3]} "
            f"(95 % interval {interval})"
        ]
    }


def _diagnosis_strength() -> dict[str, list[str]]:
    name = "diagnosis_strength.md"
    wheel = [_lead(row[4]) for row in _rows(name) if row[1:2] == ["wheel_eccentricity"]]
    needed = [float(v) for v in re.findall(r"from \|z\| = ([\d.]+);", _results(name))]
    return {
        "README.md": [
            f"no wheel case moves any spectral bin by more than {max(wheel):.1f} sd "
            f"({max(needed):.1f} needed)"
        ],
        "docs/validation.md": [
            f"no wheel case changes any 1 Hz spectral bin by more than {max(wheel):.1f} of its "
            f"standard deviations; a bin needs {_span(needed, '.2f')} to stand out"
        ],
    }


def _diagnosis_gain() -> dict[str, list[str]]:
    row = _row("diagnosis_gain.md", "frame_mode", "0")
    base, extended = row[4].removesuffix(" %"), row[6].removesuffix(" %")
    return {
        "README.md": [f"accuracy {base} -> {extended} %, ECE {row[5]} -> {row[7]}"],
        "docs/validation.md": [
            f"accuracy {base} % -> {extended} %, ECE {row[5]} -> {row[7]}",
        ],
    }


def _decision_rule() -> dict[str, list[str]]:
    ratios = [
        float(row[5].split(" +-")[0]) / float(row[2].split(" +-")[0])
        for row in _rows("decision_rule.md")
        if row[0] == "normal"
    ]
    return {
        "docs/validation.md": [
            f"under normal noise the rule's false-alarm rate is {_span(ratios, '.1f')} times that "
            "of a t-statistic above 4"
        ]
    }


def _order_segment() -> dict[str, list[str]]:
    name = "order_segment.md"
    # the rail tone at the residual map's detection limit (+13 dB: most campaigns detected), the
    # comb at its own (+6 dB) and 4 dB above it
    rail = {row[1]: row for row in _rows(name) if row[0] == "+13" and len(row) == 8}
    beyond = {segment: _lead(row[6]) for segment, row in rail.items()}
    held = [segment for segment, share in beyond.items() if share == 0]
    comb = {
        snr: {row[1]: _lead(row[2]) for row in _rows(name) if row[0] == snr and len(row) == 4}
        for snr in ("+6", "+10")
    }
    best = max(comb["+6"], key=comb["+6"].get)
    assert best == max(comb["+10"], key=comb["+10"].get)
    others = [max(v for s, v in shares.items() if s != best) for shares in comb.values()]
    return {
        "docs/validation.md": [
            f"every segment of {min(held, key=float)}-{max(held, key=float)} m locates the rail "
            f"tone within a quarter cycle over the stroke in all {rail[held[0]][2]} detected "
            f"campaigns (0.2 m: {_pct(beyond['0.2'])} % beyond)",
            f"{best} m finds it in {_pct(comb['+6'][best], 0)} % of the campaigns at its detection "
            f"limit and {_pct(comb['+10'][best], 0)} % 4 dB above, every other segment in at most "
            f"{_pct(others[0], 0)} % and {_pct(others[1], 0)} %",
        ]
    }


def _sbc() -> dict[str, list[str]]:
    name = "sbc.md"
    verdict = _find(name, r"\*\*Verdict: ([^*]+)\*\*").group(1)
    scalars = [row for row in _rows(name) if len(row) == 6 and row[0] != "scalar"]
    passed = _find(name, r"passed the sampling gates: (\d+) of (\d+)")
    return {
        "README.md": [f"{verdict} for all {len(scalars)} scalars"],
        "docs/validation.md": [
            f"{passed.group(2)} data sets",
            f"the ranks of all {len(scalars)} scalars are consistent with uniform"
            if verdict == "ranks consistent with uniform"
            else verdict,
            f"{passed.group(1)} of the {passed.group(2)} fits passed them",
        ],
    }


def _contact_law_ablation() -> dict[str, list[str]]:
    name = "contact_law_ablation.md"
    share = _find(name, r"about ([\d.]+ %) of J").group(1)
    _find(name, r"within one to two standard errors")
    laws = [row for row in _rows(name) if len(row) == 13 and row[0].isdigit()]
    return {
        "README.md": [f"contact-law ablation, {len(laws)} laws"],
        "docs/validation.md": [
            f"the {_NUMBERS[len(laws)]} contact laws fitted on the demo's healthy runs",
            f"the same J within {share} and the same ELPD within one to two standard errors",
        ],
    }


_NUMBERS = dict(
    enumerate(
        ["none", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine", "ten"]
    )
)


# --- the set-up of each result: what was measured on how much ----------------------------------


def _count(text: str) -> int:
    """How many values a command-line list gives: '0 1 2 3 4' -> 5."""
    return len(text.split())


def _classification_setup() -> dict[str, list[str]]:
    name = "classification.md"
    data = _find(name, r"(\d+) healthy calibration runs and (\d+) test runs")
    seeds = _count(_find(name, r"--seeds ([\d ]+?) --").group(1))
    bins = _find(name, r"ECE \((\d+) bins\)").group(1)
    hum = [
        _lead(cell)
        for cell in _row(
            name, "test runs + 50 Hz line of 0.03 m/s^2 (the rig's strongest mains_hum)"
        )[1:]
    ]
    default = _row(name, "posterior draws + the measured discrepancy (the default)")
    return {
        "README.md": [
            f"on {data.group(2)} rig test runs, trained on simulations only ({seeds} seeds)",
            f"({default[1].split(' ±')[0]} % there",
            f"a 50 Hz line at the rig's own level is flagged in {_span(hum, '.1f')} % of runs",
        ],
        "docs/validation.md": [
            f"On the demo campaign ({data.group(1)} healthy calibration runs, {data.group(2)} rig "
            f"test runs at three speeds)",
            f"trained on simulations only, {seeds} seeds",
            f"| ECE ({bins} bins) |",
        ],
    }


def _transfer_setup() -> dict[str, list[str]]:
    name = "transfer.md"
    command = _find(name, r"--doors (\d+) --held-out-from (\d+)")
    doors, held_from = int(command.group(1)), int(command.group(2))
    runs = _find(name, r"(\d+) healthy calibration runs fit the door; (\d+) test runs per state")
    targets = _find(name, r"targets of (\d+) % median and (\d+) % worst are not met")
    ece_target = _find(name, r"above the target ([\d.]+)\.").group(1)
    median = _lead(_row(name, "development", "`posterior+model_error`")[3])
    return {
        "README.md": [
            f"{doors} other doors the model lacks",
            f"a median of {_pct(median)} % at the quick sizes",
        ],
        "docs/validation.md": [
            f"{held_from} doors are used in development and {doors - held_from} are held out",
            f"The quick job on {doors} doors the model lacks, {runs.group(1)} healthy calibration "
            f"runs and {runs.group(2)} test runs per state each",
            f"one door of the {doors}",
            f"falls below {targets.group(2)} % without a warning",
            f"The targets ({targets.group(1)} % median, {targets.group(2)} % worst, ECE "
            f"{ece_target})",
        ],
    }


def _transfer_full_training_setup() -> dict[str, list[str]]:
    name = "transfer_full_training.md"
    quick = _find(name, r"own sizes \((\d+) simulated runs per").group(1)
    short = _find(
        name,
        r"median \([\d./ ]+\) is under (\d+) % and the median ECE \([\d./ ]+\) "
        r"over ([\d.]+)",
    )
    floor = _find(name, r"Every door is at or above (\d+) %").group(1)
    rows = [_row(name, doors, "`posterior+model_error`") for doors in ("development", "held out")]
    medians = [_pct(_lead(row[3])) for row in rows]
    return {
        "README.md": [f"{medians[0]} % / {medians[1]} % at the job's"],
        "docs/validation.md": [
            f"own generation and training sizes ({quick} simulated runs per state;",
            f"every door is at or above {floor} %; the median stays under {short.group(1)} % and "
            f"the ECE over {short.group(2)}",
        ],
    }


def _transfer_extended_setup() -> dict[str, list[str]]:
    doors = _count(_find("transfer_extended.md", r"--only ([\d ]+)`").group(1))
    return {"README.md": [f"{doors} held-out doors"]}


def _cwru_setup() -> dict[str, list[str]]:
    name = "cwru.md"
    jobs = [row for row in _rows(name) if row[0].startswith("nuts / posterior+model_error")][:3]
    named = {row[7] for row in jobs}
    segments = _find(name, r"runs of 1 s \([^)]*\) from (\d+) records")
    band = _find(name, r"envelope spectrum of the resonance band\*\* \(([\d.]+-[\d.]+ kHz)")
    rate = _find(name, r"envelope lines at a ([\d.]+) % false-alarm rate").group(1)
    return {
        "README.md": [
            f"(quick, {len(jobs)} seeds)",
            *(f"names {n} race records" for n in named if len(named) == 1),
        ],
        "docs/validation.md": [
            f"one-second segments of the {segments.group(1)} CWRU records",
            f"the envelope spectrum of {band.group(1)}",
            f"threshold from a {rate} % false-alarm rate",
        ],
    }


def _performance_setup() -> dict[str, list[str]]:
    data = json.loads(_results("performance.json"))
    run, job, targets = data["yardstick"], data["job"], data["targets"]
    door = (
        f"a {run['duration_s']:g} s door run against scipy LSODA, batch of {run['batch']}, float64 "
        f"| {run['simulate_x_scipy']:.0f}x faster ({run['batch_float64_ms_per_run']:.1f} ms a run"
    )
    quick = f"{job['wall_s']:.0f} s ({job['scipy_runs']:.0f} scipy runs"
    # as the benchmark writes them: the peak in GiB, the target in GB
    memory = f"peak memory {job['peak_memory_mb'] / 1024:.1f} GB"
    return {
        "README.md": [
            door,
            f"{quick}; target {targets['quick']:.0f} s), {memory} "
            f"(target {targets['quick_memory_mb'] / 1000:.0f} GB)",
        ],
        "docs/validation.md": [
            f"| a {run['duration_s']:g} s door run, batch of {run['batch']}, float64, against "
            f"scipy's LSODA on the same equations | {run['simulate_x_scipy']:.0f}x faster "
            f"({run['batch_float64_ms_per_run']:.1f} ms a run) |",
            f"| {quick}), of it",
            f"s compiling, {memory}, the posterior",
        ],
    }


def _diagnosis_setup() -> dict[str, list[str]]:
    command = _find("diagnosis.md", r"--seeds ([\d ]+?) --none-seeds [\d ]+ --runs (\d+)")
    runs, seeds = command.group(2), _count(command.group(1))
    return {
        "README.md": [f"{runs} runs per campaign, {seeds} seeds per effect"],
        "docs/validation.md": [f"| {runs} runs, {seeds} seeds per effect, quick sizes |"],
    }


def _diagnosis_full_size_setup() -> dict[str, list[str]]:
    name = "diagnosis_full_size.md"
    runs = _find(name, r"\d+ of (\d+) runs gain").group(1)
    cases = [
        row[0].rsplit(" ", 1)[0] for row in _rows(name) if re.fullmatch(r"[a-z_]+ \d+", row[0])
    ]
    seeds = {cases.count(effect) for effect in set(cases)}
    assert len(seeds) == 1, "results/diagnosis_full_size.md: as many seeds for every effect"
    setup = f"{runs} runs, {seeds.pop()} seeds per effect"
    within = sum(row[7] == "pass" for row in _rows(name) if re.fullmatch(r"frame_mode \d+", row[0]))
    return {
        "README.md": [setup],
        "docs/validation.md": [
            f"| {setup}, each campaign's own fit |",
            f"(its frequency within tolerance in {within})",
        ],
    }


def _diagnosis_limits_setup() -> dict[str, list[str]]:
    name = "diagnosis_limits.md"
    power = _find(name, r"limit \((\d+) %\)").group(1)
    seeds = _find(name, r"--seeds (\d+)").group(1)
    runs = _find(name, r"nothing-hidden (\d+)-run campaign").group(1)
    factors = sorted({row[1] for row in _rows(name) if re.fullmatch(r"[\d.]+", row[1])}, key=float)
    limit = _row(name, "wheel_eccentricity")[3]
    return {
        "README.md": [
            f"detection limits ({power} % power) at {factors[-1]}x / {factors[0]}x, {seeds} "
            "new rig seeds",
            f"below its limit of {limit}",
        ],
        "docs/validation.md": [
            f"| detection limits ({power} % power) on a {runs}-run campaign, each cause hidden "
            f"at {' and '.join(factors)} times its limit, {seeds} seeds not used while building",
        ],
    }


def _diagnosis_transmission() -> dict[str, list[str]]:
    name = "diagnosis_transmission.md"
    groups = [row[1] for row in _rows(name) if row[1] in ("development", "held-out")]
    factor = _find(name, r"hidden at ([\d.]+) times the door's model limit").group(1)
    hum = _row(name, "mains_hum")
    leak = _row(name, "sensor_cross_axis")
    rail, wheel = (
        f"{100 * float(_row(name, c)[3]):.0f}" for c in ("rail_waviness", "wheel_eccentricity")
    )
    low = hum[2].split("-")[0]
    return {
        "docs/validation.md": [
            f"on each of {groups.count('development')} development and "
            f"{groups.count('held-out')} held-out doors, each cause hidden at {factor} times",
            f"as the model shows {hum[2]} times the size, so the family limit is "
            f"{float(hum[4]):.1f} times the model limit (held out: "
            f"{hum[5].split(' of ')[0]} of {hum[5].split(' of ')[1]} doors at or above {low})",
            f"sized on the measured signals: {leak[2]}",
            f"at worst {rail} % and {wheel} % of a door's change explained",
        ],
    }


def _diagnosis_plan_wheel_setup() -> dict[str, list[str]]:
    name = "diagnosis_plan_wheel.md"
    plan = _find(name, r"From the nothing-hidden (\d+)-run campaign")
    size = _row(name, "wheel_eccentricity")[1]
    return {
        "docs/validation.md": [
            f"`plan_campaign` for a {size} wheel from the {plan.group(1)}-run campaign"
        ]
    }


def _diagnosis_gain_setup() -> dict[str, list[str]]:
    runs = _find("diagnosis_gain.md", r"With (\d+) test runs per case").group(1)
    return {
        "README.md": [f"({runs} test runs, quick sizes)"],
        "docs/validation.md": [f"added to the model, {runs} test runs"],
    }


def _decision_rule_setup() -> dict[str, list[str]]:
    draws = int(
        _find("decision_rule.md", r"False alarms under noise \((\d+) draws per row").group(1)
    )
    return {"docs/validation.md": [f"{draws:,} draws per row"]}


def _order_segment_setup() -> dict[str, list[str]]:
    setup = _find(
        "order_segment.md",
        r"(\d+) rail campaigns \(each at every SNR\) and (\d+) comb campaigns, seed \d+\. "
        r"Each campaign: (\d+-\d+) runs",
    )
    harmonics = _find("order_segment.md", r"harmonics (\d+) and (\d+)")
    return {
        "docs/validation.md": [
            f"synthetic campaigns of {setup.group(3)} runs in white noise ({setup.group(1)} with "
            f"a rail tone at each SNR, {setup.group(2)} with wheel harmonics "
            f"{harmonics.group(1)} and {harmonics.group(2)})",
        ]
    }


def _sbc_setup() -> dict[str, list[str]]:
    sets = _find("sbc.md", r"passed the sampling gates: \d+ of (\d+)").group(1)
    return {"README.md": [f"({sets} data sets, surrogate forward)"]}


SETUP: dict[str, Callable[[], dict[str, list[str]]]] = {
    "classification.md": _classification_setup,
    "transfer.md": _transfer_setup,
    "transfer_full_training.md": _transfer_full_training_setup,
    "transfer_extended.md": _transfer_extended_setup,
    "cwru.md": _cwru_setup,
    "performance.md": _performance_setup,
    "diagnosis.md": _diagnosis_setup,
    "diagnosis_full_size.md": _diagnosis_full_size_setup,
    "diagnosis_limits.md": _diagnosis_limits_setup,
    "diagnosis_plan_wheel.md": _diagnosis_plan_wheel_setup,
    "diagnosis_gain.md": _diagnosis_gain_setup,
    "decision_rule.md": _decision_rule_setup,
    "order_segment.md": _order_segment_setup,
    "sbc.md": _sbc_setup,
}


def _with_setup(
    name: str, results: Callable[[], dict[str, list[str]]]
) -> Callable[[], dict[str, list[str]]]:
    """A results file's figures and its set-up figures, per page."""

    def figures() -> dict[str, list[str]]:
        merged = {page: list(lines) for page, lines in results().items()}
        for page, lines in SETUP.get(name, dict)().items():
            merged.setdefault(page, []).extend(lines)
        return merged

    return figures


_RESULTS_FIGURES: dict[str, Callable[[], dict[str, list[str]]]] = {
    "classification.md": _classification,
    "transfer.md": _transfer,
    "transfer_full_training.md": _transfer_full_training,
    "transfer_extended.md": _transfer_extended,
    "cwru.md": _cwru,
    "performance.md": _performance,
    "diagnosis.md": _diagnosis,
    "diagnosis_full_size.md": _diagnosis_full_size,
    "diagnosis_limits.md": _diagnosis_limits,
    "diagnosis_limits_hum.md": _diagnosis_limits_hum,
    "hum_interference.md": _hum_interference,
    "inference.md": _inference,
    "diagnosis_plan_wheel.md": _diagnosis_plan_wheel,
    "diagnosis_strength.md": _diagnosis_strength,
    "diagnosis_gain.md": _diagnosis_gain,
    "decision_rule.md": _decision_rule,
    "order_segment.md": _order_segment,
    "sbc.md": _sbc,
    "contact_law_ablation.md": _contact_law_ablation,
    "diagnosis_transmission.md": _diagnosis_transmission,
}
FIGURES = {name: _with_setup(name, f) for name, f in _RESULTS_FIGURES.items()}


def _blocks(page: str) -> list[str]:
    """The page's paragraphs, list items and table rows, each on one line."""
    text = (ROOT / page).read_text(encoding="utf-8")
    if page == "README.md":
        text = text.split("## What it achieves", 1)[1].split("\n## ", 1)[0]
    blocks: list[str] = []
    for chunk in re.split(r"\n\s*\n", text):
        if not chunk.lstrip().startswith("|"):
            blocks += re.split(r"\n(?=- )", chunk)
        elif "results/" in chunk:  # each row cites its own file
            blocks += chunk.strip().splitlines()
        elif blocks:  # a table read with the paragraph that introduces it and cites its file
            blocks[-1] += "\n" + chunk
    return [" ".join(block.split()) for block in blocks]


CASES = [
    pytest.param(page, name, id=f"{page}:{name}")
    for name, figures in FIGURES.items()
    for page in ("README.md", "docs/validation.md")
    if page in figures()
]


@pytest.mark.parametrize(("page", "name"), CASES)
def test_the_page_quotes_the_figures_of_the_file_it_cites(page, name):
    citing = [block for block in _blocks(page) if f"results/{name}" in block]
    assert citing, f"{page} cites results/{name} nowhere"
    missing = [
        figure
        for figure in FIGURES[name]()[page]
        if not any(" ".join(figure.split()) in block for block in citing)
    ]
    assert not missing, (
        f"{page}, where it cites results/{name}, does not say (as the results file gives it):\n"
        + "\n".join(missing)
    )


def test_the_readme_figure_is_the_quick_job_of_the_results():
    accuracy, ece = _quick_job()
    caption = " ".join((ROOT / "README.md").read_text(encoding="utf-8").split())
    assert f"({accuracy}, {ece}: the quick job of [results/performance.md]" in caption


@pytest.mark.parametrize("page", ["README.md", "docs/validation.md"])
def test_every_results_file_the_page_cites_has_its_figures_checked(page):
    # a results file the page cites with no entry in FIGURES would go unchecked
    cited = {
        name for block in _blocks(page) for name in re.findall(r"results/([a-z_]+\.md)", block)
    }
    quoted = {name for p, name in (case.values for case in CASES) if p == page}
    assert cited - quoted == set(), f"{page} cites results files no test reads: {cited - quoted}"


@pytest.mark.parametrize("page", ["README.md", "docs/validation.md"])
def test_the_commits_the_page_names_are_those_of_the_files_it_cites(page):
    wrong = []
    for block in _blocks(page):
        files = set(re.findall(r"results/([a-z_]+\.md)", block))
        for commit in re.findall(r"\bcommits? ((?:[0-9a-f]{7,40}(?:, | and )?)+)", block):
            for sha in re.findall(r"[0-9a-f]{7,40}", commit):
                if files and not any(sha in _results(name) for name in files):
                    wrong.append(f"{sha} (cited with {', '.join(sorted(files))})")
    assert not wrong, f"{page} names commits its results files do not: {wrong}"


#: a command as a results file writes it: a script, a benchmark, a test run or the CLI
COMMAND = re.compile(r"`(?:\.venv/bin/)?(?:python3? |pytest |bayesdoor |/usr/bin/time )[^`]+`")
DATE = re.compile(
    r"\b20\d\d-\d\d-\d\d\b|\b(?:Mon|Tue|Wed|Thu|Fri|Sat|Sun) \w{3} +\d+ [\d:]+ \w+ 20\d\d"
)
COMMIT = re.compile(r"(?:\bcommits?:?|\brecorded in|\|) ([0-9a-f]{7,40})\b")


@pytest.mark.parametrize(
    "path", sorted(RESULTS.glob("*.md")), ids=lambda p: p.relative_to(ROOT).as_posix()
)
def test_every_results_file_names_its_command_date_and_commit(path):
    head = "\n".join(path.read_text(encoding="utf-8").splitlines()[:15])
    missing = [
        what
        for what, pattern in (("command", COMMAND), ("date", DATE), ("commit", COMMIT))
        if not pattern.search(head)
    ]
    assert not missing, f"{path.name}'s first lines do not name its {', '.join(missing)}"


def test_the_span_prints_what_the_pages_print():
    assert _span([0.750, 0.750, 0.792], ".2f") == "0.75-0.79"
    assert _span([0.917, 0.917], ".3f") == "0.917"
    assert _span([89, 128, 99], "d") == "89-128"


# --- every number the pages print is one of the figures above -------------------------------

#: a date as the pages and the results files write it
DAY = re.compile(r"\b\d{4}-\d{2}-\d{2}\b")
#: a number as a figure: 92.3, 200,000, 4 of 4/5, 1.5 of 1.5x; not the digits of a name
#: (H100, float64, A1, D2, log10), a commit (2d547b2) or a file (diagnosis_limits.md)
NUMBER = re.compile(
    r"(?<![\w.])\d{1,3}(?:,\d{3})+(?![\w])|(?<![\w.])\d+(?:\.\d+)?(?![a-wyzA-Z_\d])"
)
#: what a number in a page does not count as a figure within: code spans, link targets, commits
_NOT_PROSE = re.compile(r"`[^`]*`|\]\([^)]*\)|\b[0-9a-f]{7,40}\b")
#: numbers that describe the machine the figures were measured on, not a result
MACHINE = {"2-core"}


def _numbers(text: str) -> list[str]:
    text = _NOT_PROSE.sub(" ", text)
    text = DAY.sub(" ", text)
    for phrase in MACHINE:
        text = text.replace(phrase, " ")
    return NUMBER.findall(text)


def _measured_blocks(page: str) -> list[str]:
    blocks = _blocks(page)
    if page == "docs/validation.md":  # the page's introduction has no figure
        blocks = [b for b in blocks if not b.startswith("# ")]
    return [b for b in blocks if _numbers(b)]


@pytest.mark.parametrize("page", ["README.md", "docs/validation.md"])
def test_every_number_the_page_prints_is_a_figure_of_the_file_it_cites(page):
    unsourced = []
    for block in _measured_blocks(page):
        files = set(re.findall(r"results/([a-z_]+\.md)", block))
        figures = {
            n
            for name in files
            if name in FIGURES
            for n in _numbers(" ".join(FIGURES[name]().get(page, [])))
        }
        loose = [n for n in _numbers(block) if n not in figures]
        if loose:
            unsourced.append(f"{', '.join(loose)} in: {block[:100]}...")
    assert not unsourced, (
        f"{page} prints numbers that no results file it cites gives (cite the file and add the "
        "figure to FIGURES, or remove the number):\n" + "\n".join(unsourced)
    )


@pytest.mark.parametrize("page", ["README.md", "docs/validation.md"])
def test_the_dates_the_page_names_are_those_of_the_files_it_cites(page):
    wrong = []
    for block in _blocks(page):
        files = set(re.findall(r"results/([a-z_]+\.md)", block))
        for day in DAY.findall(block):
            if not any(day in _results(name) for name in files):
                wrong.append(f"{day} (cited with {', '.join(sorted(files)) or 'no results file'})")
    assert not wrong, f"{page} names dates its results files do not: {wrong}"
