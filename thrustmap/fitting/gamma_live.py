"""γ(B) fitted while the vehicle flies: the Df and γ of a telemetry stream so far.

``LiveGamma`` reads a ``Telemetry`` (fed message by message elsewhere) and, when asked, builds
its FlightLog and runs **the same code** as `flightlog extract` (``df.extract``) and `gamma fit`
(``gamma.fit_gamma``) on everything received so far. Extraction and fit are re-run on the whole
stream (their filters look ahead and behind, a steady-state window and the takeoff/landing
margins, so a sample is only final once the flight has moved on); ``due()`` spaces the refits so
that they take at most ``MAX_BUSY_SHARE`` of the time, whatever the flight's length. The final
result comes from one extraction over the whole stream, so a replayed recording gives the same
numbers as the live run.

Besides γ(B) a ``LiveState`` carries what the live panel shows: samples kept and why others
were dropped, voltage bins with the mean γ and its 95 % interval, the throttle the map gives at
hover with and without γ, and our hover throttle beside the vehicle's own estimate when there
is one (PX4: MPC_THR_HOVER, the value its hover-thrust estimator starts from; the estimate
itself is in the ULog, it is not streamed).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from thrustmap.core.errors import ThrustmapError
from thrustmap.fitting.df.extraction import extract
from thrustmap.fitting.df.options import G0, MIN_DF_SAMPLES
from thrustmap.fitting.df.table import Df
from thrustmap.fitting.df_options import DfOptions
from thrustmap.flightlogs.telemetry import Telemetry

if TYPE_CHECKING:
    from thrustmap.fitting.gamma import GammaFit
    from thrustmap.fitting.mapfile import ThrustMap

log = logging.getLogger(__name__)

#: refits take at most this share of the time (a refit that took 0.2 s waits 2 s)
MAX_BUSY_SHARE = 0.1
MIN_REFIT_INTERVAL_S = 2.0
Z95 = 1.959964


@dataclass
class VoltageBin:
    lo_v: float
    hi_v: float
    samples: int
    gamma_mean: float
    gamma_ci95: float  # half-width of the 95 % interval of the mean γ in the bin


@dataclass
class LiveState:
    """One refit's result; ``gamma_fit`` None when γ is not determined (``why_not`` says)."""

    duration_s: float = 0.0
    samples: int = 0
    kept_s: float = 0.0
    dropped: list[tuple[str, float, str]] = field(default_factory=list)  # name, s, reason
    warnings: list[str] = field(default_factory=list)
    bins: list[VoltageBin] = field(default_factory=list)
    gamma_fit: GammaFit | None = None
    why_not: str | None = None
    voltage_now_v: float | None = None
    hover_uncorrected_pct: float | None = None
    hover_corrected_pct: float | None = None
    hover_ours: float | None = None  # normalised collective command at hover, from the Df
    hover_vehicle: float | None = None  # the vehicle's own hover estimate (normalised)
    hover_vehicle_source: str | None = None
    df: Df | None = None


class LiveGamma:
    """Df and γ(B) of a telemetry stream so far; see the module docstring."""

    def __init__(
        self,
        telemetry: Telemetry,
        opts: DfOptions,
        tmap: ThrustMap,
        *,
        loss: str = "l1",
        clock: Any = time.perf_counter,
    ) -> None:
        if opts.mass_kg is None:
            raise ThrustmapError("gamma live needs the vehicle mass (--mass-kg)")
        self.telemetry = telemetry
        self.opts = opts
        self.tmap = tmap
        self.loss = loss
        self._clock = clock
        self._last_refit_t: float | None = None
        self._next_interval_s = MIN_REFIT_INTERVAL_S
        self.state = LiveState()

    def due(self, stream_t_s: float) -> bool:
        """A refit is due at stream time ``stream_t_s``."""
        return (
            self._last_refit_t is None or stream_t_s - self._last_refit_t >= self._next_interval_s
        )

    def refit(self, stream_t_s: float | None = None) -> LiveState:
        started = self._clock()
        with _quiet_fitting():  # a refit's warnings are shown by the panel, not logged each time
            self.state = self.compute()
        spent = self._clock() - started
        self._next_interval_s = max(MIN_REFIT_INTERVAL_S, spent / MAX_BUSY_SHARE)
        if stream_t_s is not None:
            self._last_refit_t = stream_t_s
        return self.state

    def compute(self, *, quiet: bool = False) -> LiveState:
        """Extract the Df and fit γ(B) on everything received so far (``quiet``: their
        warnings are kept in the state, not logged)."""
        if quiet:
            with _quiet_fitting():
                return self.compute()
        st = LiveState()
        tel = self.telemetry
        if tel.acceleration_source() is None:
            st.why_not = "no acceleration in the stream yet"
            return st
        flight = tel.flight_log()
        try:
            df = extract([flight], self.opts, self.tmap)
        except ThrustmapError as exc:
            st.why_not = str(exc)
            return st
        st.df = df
        report = df.reports[0]
        st.duration_s = report.duration_s
        st.samples = report.samples
        st.kept_s = report.kept_s
        st.dropped = [(s.name, s.dropped_s, s.reason) for s in report.steps if s.dropped_s > 0]
        st.warnings = list(report.warnings)
        if flight.voltage_v is not None and len(flight.voltage_v):
            st.voltage_now_v = float(flight.voltage_v.values[-1])
        self._vehicle_hover(st)
        if report.samples < MIN_DF_SAMPLES:
            st.why_not = f"{report.samples} Df samples so far; a γ fit needs {MIN_DF_SAMPLES}"
            return st
        table = df.table
        from thrustmap.fitting.gamma import GammaOptions, fit_gamma

        try:
            how = GammaOptions(loss="l1" if self.loss == "l1" else "l2")
            fit = fit_gamma(table, df.sources, self.tmap, how)
        except ThrustmapError as exc:
            st.why_not = str(exc)
            return st
        st.gamma_fit = fit
        st.bins = [
            VoltageBin(
                row["voltage_v"][0],
                row["voltage_v"][1],
                int(row["samples"]),
                float(row["gamma"]["mean"]),
                Z95 * float(row["gamma"]["std"]) / np.sqrt(max(int(row["samples"]), 1)),
            )
            for row in fit.metrics.get("by_voltage", [])
        ]
        if not fit.corrected:
            st.why_not = "no γ(B) keeps the map no worse in every populated voltage bin"
        self._hover(st, table, fit)
        return st

    def _vehicle_hover(self, st: LiveState) -> None:
        params = self.telemetry.params
        for name in ("MPC_THR_HOVER", "MOT_THST_HOVER"):
            if name in params:
                st.hover_vehicle = float(params[name])
                st.hover_vehicle_source = f"{name} (parameter)"
                return

    def _hover(self, st: LiveState, table: Any, fit: GammaFit) -> None:
        mass = float(self.opts.mass_kg or 0.0)
        rotors = fit_rotors(st.df)
        if st.voltage_now_v is not None and rotors:
            per_rotor = mass * G0 / rotors
            b = st.voltage_now_v
            corr = self.tmap.with_correction(fit.correction)
            st.hover_uncorrected_pct = float(self.tmap.throttle_pct(per_rotor, b, corrected=False))
            st.hover_corrected_pct = float(corr.throttle_pct(per_rotor, b))
        if "thrust_cmd_norm" in table.columns and len(table):
            from thrustmap.fitting.df.table import hover_throttle

            try:
                st.hover_ours = hover_throttle(table)
            except ThrustmapError:
                st.hover_ours = None


@contextmanager
def _quiet_fitting() -> Iterator[None]:
    """Warnings of the extraction and the fit below ERROR are not logged inside the block."""
    target = logging.getLogger("thrustmap.fitting")
    previous = target.level
    target.setLevel(logging.ERROR)
    try:
        yield
    finally:
        target.setLevel(previous)


def fit_rotors(df: Df | None) -> int | None:
    if df is None:
        return None
    for meta in df.sources.get("flights", {}).values():
        if meta.get("rotors"):
            return int(meta["rotors"])
    return None
