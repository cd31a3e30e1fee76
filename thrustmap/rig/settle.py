"""Live settle detection: is the thrust still trending, while the run is going on?

The runner asks two questions of the last second or so of stand samples:

- ``SettleDetector``: has thrust settled at the level just commanded (``--settle`` holds end
  ``record_s`` after this)?
- ``RestDetector``: is the rotor at rest (thrust steady, rpm ~0 where measured), so the stand can
  be tared?

Both use ``steady``: the means of the window's two halves agree within the window's own noise.
They run causally on a short sliding window, sample by sample.

The OFFLINE detector that picks steady-state points out of a finished Ds log is
``thrustmap.fitting.selection`` (``_settle_index``/``_steady_state``): it sees the whole
plateau, so it may cut the transient differently; the two are kept apart on purpose (one
decides when to move on, the other which samples to fit) but sit side by side by name.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable

import numpy as np
import numpy.typing as npt

from thrustmap.rig.interfaces import StandSample

#: rpm above which a rotor is turning (where the stand measures rpm)
TURNING_RPM = 100.0


def steady(values: npt.NDArray[np.float64], floor: float) -> bool:
    """No trend left: the means of the window's two halves agree within the window's own noise
    (4 standard errors) or within ``floor``. A settling rotor trends; a settled one only wobbles."""
    half = len(values) // 2
    if half < 3:
        return False
    noise = float(np.std(values)) / np.sqrt(half)
    return bool(abs(float(values[:half].mean() - values[half:].mean())) <= max(floor, 4.0 * noise))


class _Window:
    def __init__(self, window_s: float) -> None:
        self.window_s = window_s
        self.points: deque[tuple[float, float]] = deque()

    def add(self, now_s: float, samples: Iterable[tuple[float, float]]) -> None:
        self.points.extend(samples)
        while self.points and self.points[0][0] < now_s - self.window_s:
            self.points.popleft()

    def spans(self, min_points: int) -> bool:
        p = self.points
        return len(p) >= min_points and p[-1][0] - p[0][0] >= 0.8 * self.window_s

    def values(self) -> npt.NDArray[np.float64]:
        return np.array([v for _, v in self.points])


class SettleDetector:
    """Thrust settled at a level: steady over ``window_s`` within ``max(band_n, rel × thrust)``."""

    def __init__(self, window_s: float, band_n: float, rel: float) -> None:
        self.window = _Window(window_s)
        self.band_n = band_n
        self.rel = rel

    def update(self, now_s: float, samples: Iterable[StandSample]) -> bool:
        self.window.add(now_s, ((s.time_s, s.thrust_n) for s in samples))
        if not self.window.spans(5):
            return False
        values = self.window.values()
        return steady(values, max(self.band_n, self.rel * abs(float(values.mean()))))


class RestDetector:
    """The rotor is at rest: thrust steady (within 5 mN) over ``window_s`` and no sample with
    rpm above ``TURNING_RPM`` in it."""

    def __init__(self, window_s: float, floor_n: float = 0.005) -> None:
        self.window = _Window(window_s)
        self.floor_n = floor_n
        #: why the last update said "not at rest" (for the message when the wait gives up)
        self.why_not = "no stand reading yet"

    def update(self, now_s: float, samples: Iterable[StandSample]) -> bool:
        turning = False
        for s in samples:
            if s.rpm is not None and s.rpm > TURNING_RPM:
                self.window.points.clear()
                self.why_not = f"the stand reads {s.rpm:.0f} rpm"
                turning = True
                continue
            self.window.add(now_s, [(s.time_s, s.thrust_n)])
        self.window.add(now_s, ())
        if turning and not self.window.points:
            return False
        if not self.window.spans(6):
            p = self.window.points
            span = p[-1][0] - p[0][0] if p else 0.0
            self.why_not = (
                f"{len(p)} stand readings over {span:.2f} s in the last "
                f"{self.window.window_s:g} s (needs 6 over {0.8 * self.window.window_s:g} s)"
            )
            return False
        values = self.window.values()
        if not steady(values, self.floor_n):
            self.why_not = (
                f"thrust still moving ({values.min():+.3f}..{values.max():+.3f} N "
                f"over {self.window.window_s:g} s)"
            )
            return False
        return True
