"""``bayesdoor simulate``: runs of a registered system's model, written as a campaign."""

from __future__ import annotations

from typing import Any

import numpy as np

from ._common import fail


def reference_values(system) -> dict[str, float]:
    """Each parameter's reference value (a published optimum, say), else its nominal one."""
    return {
        p.name: float(p.nominal if p.reference_value is None else p.reference_value)
        for p in system.parameters
    }


def operating_points(system, conditions: dict[str, list[float]], runs: int) -> np.ndarray:
    """The runs' operating conditions from ``--condition`` values (one, or one per run)."""
    names = system.condition_names()
    unknown = sorted(set(conditions) - set(names))
    if unknown:
        raise fail(
            f"--condition {', '.join(unknown)}: {system.name} has the conditions {', '.join(names)}"
        )
    missing = [n for n in names if n not in conditions]
    if missing:
        raise fail(f"give --condition {missing[0]}=VALUE ({system.name} needs {', '.join(names)})")
    columns = []
    for spec in system.conditions:
        values = conditions[spec.name]
        if len(values) not in (1, runs):
            raise fail(
                f"--condition {spec.name} takes one value or one per --state ({runs}), got "
                f"{len(values)}"
            )
        try:
            spec.check(values)
        except ValueError as err:
            raise fail(f"--condition {err}") from None
        columns.append(np.broadcast_to(np.asarray(values, dtype=float), (runs,)))
    return columns[0] if len(columns) == 1 else np.stack(columns, axis=-1)


def simulate_campaign(system, states, operating, *, seed: int, params, progress):
    """Simulate one run per (state, operating point) with ``system``'s model.

    Severities are drawn from each state's uniform priors with ``seed``; a run's severities
    of other states are 0. Returns the campaign dataset (``bayesdoor.io.make_campaign``).
    """
    from ..io import make_campaign

    for s in states:
        if s not in system.states:
            raise fail(f"unknown state {s!r}: allowed {', '.join(system.states)}")
    values = {**reference_values(system), **params}
    try:
        system.check_parameters(values)
    except ValueError as err:
        raise fail(str(err)) from None
    rng = np.random.default_rng(seed)
    names = sorted({k for s in states for k in system.states[s].severity})
    severities: dict[str, Any] = {k: np.zeros(len(states)) for k in names}
    for i, state in enumerate(states):
        for k, (lo, hi) in system.states[state].severity.items():
            severities[k][i] = rng.uniform(lo, hi) if hi > lo else lo
    duration = float(system.record_duration(operating))
    signals = None
    with progress(f"simulating {len(states)} runs"):
        for state in dict.fromkeys(states):
            at = np.flatnonzero(np.asarray(states) == state)
            res = system.simulate_values(
                values,
                operating[at],
                state=state,
                severity={k: severities[k][at] for k in system.states[state].severity},
                duration=duration,
            )
            status = np.asarray(res.status)
            if np.any(status != 0):
                bad = at[np.flatnonzero(status)]
                raise fail(f"the solve failed for runs {bad.tolist()} (status {status.tolist()})")
            x = np.asarray(res.signals, dtype=float)
            if signals is None:
                signals = np.zeros((len(states), *x.shape[1:]))
            signals[at] = x
    t_start, t_stop = system.motion_window(operating, duration=duration)
    assert signals is not None
    per_run: dict[str, Any] = (
        {system.conditions[0].name: np.asarray(operating, dtype=float)}
        if np.ndim(operating) == 1
        else {c.name: np.asarray(operating)[:, i] for i, c in enumerate(system.conditions)}
    )
    return make_campaign(
        signals,
        channels=list(system.channels),
        fs=system.sampling_rate_hz,
        state=list(states),
        system=system.name,
        t_start=np.broadcast_to(np.asarray(t_start, dtype=float), (len(states),)),
        t_stop=np.broadcast_to(np.asarray(t_stop, dtype=float), (len(states),)),
        **per_run,
        **severities,
    )
