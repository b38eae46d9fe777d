"""The colours of a system's states, one per state and the same in every figure."""

from __future__ import annotations

from collections.abc import Sequence

from ..io import UNKNOWN

#: the healthy state's colour in every figure (matplotlib's ``tab:green``)
HEALTHY_COLOR = "#2ca02c"
#: the colour of the runs whose state is not known (the campaign label ``unknown``)
UNKNOWN_COLOR = "#737373"
#: the qualitative colormap the other states take their colours from, in order
STATE_COLORMAP = "tab10"


def state_colors(states: Sequence[str], healthy: str) -> dict[str, str]:
    """A colour (``#rrggbb``) for each of ``states``, in their order.

    ``healthy`` (the system's :attr:`~bayesdoor.systems.AbstractSystem.healthy`) gets
    :data:`HEALTHY_COLOR` and the label ``unknown`` :data:`UNKNOWN_COLOR`; the other states
    take the colours of the qualitative colormap :data:`STATE_COLORMAP` in order, less its
    healthy colour and its greys (they repeat after the colormap's last). Pass the system's
    states (or an ensemble's classes) in one order to every figure of a job, so that a state
    keeps its colour from figure to figure.

    Examples
    --------
    >>> state_colors(["ok", "crack", "loose"], "ok")
    {'ok': '#2ca02c', 'crack': '#1f77b4', 'loose': '#ff7f0e'}
    """
    import matplotlib
    from matplotlib.colors import to_hex

    cmap = matplotlib.colormaps[STATE_COLORMAP]
    cycle = [
        c
        for c in (to_hex(cmap(i)) for i in range(cmap.N))
        if c != HEALTHY_COLOR and len({c[1:3], c[3:5], c[5:7]}) > 1
    ]
    colors: dict[str, str] = {}
    others = 0
    for state in dict.fromkeys(states):
        if state == healthy:
            colors[state] = HEALTHY_COLOR
        elif state == UNKNOWN:
            colors[state] = UNKNOWN_COLOR
        else:
            colors[state] = cycle[others % len(cycle)]
            others += 1
    return colors
