"""One flight's extraction as its rules run (``FlightRun``): the flight on one timeline of bins,
each signal binned once, the filters' keep mask with each filter's step, and the warnings.
``df.extraction`` builds one and runs its rules over it; ``df.airborne``'s rules read it."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from thrustmap.fitting.df.options import BoolArray, FilterStep
from thrustmap.fitting.df.resample import bin_mean
from thrustmap.fitting.df_options import DfOptions
from thrustmap.flightlogs.series import FlightLog, FloatArray, Signal

if TYPE_CHECKING:
    from thrustmap.fitting.mapfile import ThrustMap


@dataclass
class FlightRun:
    """What every rule of one flight's extraction reads and adds to."""

    flight: FlightLog
    opts: DfOptions
    tmap: ThrustMap | None
    mass_kg: float
    #: the upward specific force on a plausible timeline, in m/s²
    acc: Signal
    #: the first bin's start (the first accelerometer sample) and the number of bins
    t0: float
    nbins: int
    #: why the battery voltage is unknown (None: the log has one), and the Df's note on it
    voltage_missing: str | None
    voltage_unknown: str | None
    warnings: list[str]
    keep: BoolArray = field(init=False)
    centres: FloatArray = field(init=False)
    steps: list[FilterStep] = field(default_factory=list)
    #: set by the first rules: a_up (binned, smoothed, calibrated at rest), the voltage, the
    #: bins with an accelerometer sample, the tilt, airborne by the land state, and the
    #: command that tells steady flight (its unit the log's) and the same in %
    a_up: FloatArray = field(init=False)
    volt: FloatArray = field(init=False)
    has_data: BoolArray = field(init=False)
    tilt: FloatArray | None = None
    airborne: BoolArray = field(init=False)
    cmd_steady: FloatArray | None = None
    cmd_pct: FloatArray | None = None
    _binned: dict[int, FloatArray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.keep = np.ones(self.nbins, bool)
        self.airborne = np.ones(self.nbins, bool)
        self.centres = np.asarray(
            self.t0 + (np.arange(self.nbins) + 0.5) * self.dt_s, dtype=np.float64
        )

    @property
    def dt_s(self) -> float:
        return 1.0 / self.opts.rate_hz

    def rs(self, sig: Signal | None) -> FloatArray | None:
        """``sig`` on the bins (each signal binned once; callers do not mutate the result)."""
        if sig is None:
            return None
        if id(sig) not in self._binned:
            self._binned[id(sig)] = bin_mean(
                sig, self.t0, self.opts.rate_hz, self.nbins, self.opts.max_gap_s
            )
        return self._binned[id(sig)]

    def apply(self, name: str, reason: str, ok: BoolArray) -> None:
        """A filter: keep only the bins where ``ok``, recording the time it dropped."""
        before = self.keep.sum()
        self.keep = self.keep & ok
        dt = self.dt_s
        self.steps.append(
            FilterStep(
                name, reason, float((before - self.keep.sum()) * dt), float(self.keep.sum() * dt)
            )
        )
