"""Which voltages a map was measured at (issue 30 item 4): the points' voltages in groups.

``fit`` stores them in the map (``selection.measured_voltages_v``) and prints them; the
adaptive bench's across-voltage plan (``thrustmap.fitting.adaptive``) is what fills more than
one group.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

#: points whose voltages lie within this share of each other are one measured voltage
VOLTAGE_GROUP_REL = 0.05


def measured_voltages(voltage_v: npt.ArrayLike) -> list[dict[str, float]]:
    """The voltages a map was measured at: its points' voltages grouped where they lie within
    ``VOLTAGE_GROUP_REL`` of the next (a discharge's continuous fall is one group from its
    start to its end), each group as ``{"lo_v", "median_v", "hi_v", "points"}``, ascending."""
    b = np.sort(np.asarray(voltage_v, float))
    b = b[np.isfinite(b) & (b > 0)]
    if not len(b):
        return []
    groups: list[list[float]] = [[float(b[0])]]
    for x in b[1:].tolist():
        if x - groups[-1][-1] > VOLTAGE_GROUP_REL * groups[-1][-1]:
            groups.append([x])
        else:
            groups[-1].append(x)
    return [
        {
            "lo_v": round(g[0], 3),
            "median_v": round(float(np.median(g)), 3),
            "hi_v": round(g[-1], 3),
            "points": float(len(g)),
        }
        for g in groups
    ]


def describe_voltages(groups: Sequence[dict[str, float]]) -> str:
    """``measured_voltages`` in words: "24.12..24.86 V (31 points) and 21.90..22.41 V (40)"."""
    return " and ".join(
        f"{g['lo_v']:.2f}..{g['hi_v']:.2f} V ({g['points']:.0f} points)" for g in groups
    )
