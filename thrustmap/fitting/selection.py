"""Which samples a fit sees: range filters and steady-state extraction.

Range filters use the seed paper's strict inequalities, in the data's native units.

Steady state (default): a step sweep holds each throttle level for seconds, but the rotor
needs time to spin up and the stand averages over its own window, so the first samples of each
plateau are transients. For every plateau (consecutive samples at one throttle) we estimate the
thrust noise from the second half of the plateau, drop the leading samples until thrust has
settled inside that noise band, and average the rest into one (T, B, Th) point. On ramps,
samples are kept only where the throttle slews slowly enough that rotor lag costs less than
``lag_budget_pct`` of throttle (quasi-static). ``all_samples`` reproduces the paper (no
extraction).

Sensors, not samples: a load cell that updates every ~10 samples and holds its value in between
(sample-and-hold, e.g. the Crazyflie system-id stand) is detected from its exact repeats, and
settling, noise and plateau length are judged on its UPDATES. A plateau whose kept part still
trends (the means of its two halves differ beyond the noise) is dropped.

Quasi-static staircases: a command held for about one sensor update per step (the Crazyflie
system-id deck: 10 ms rows, a new command every 100 ms, a load cell converting at ~10 SPS) is a
slow ramp seen through the sensor, not a staircase of unsettled plateaus. A pair of adjacent
legs (up then down, or down then up; at least ``min_stair_legs`` stairs each) is treated so
when its stairs last fewer than ``quasi_static_updates`` sensor updates or less than
``quasi_static_lags`` times the lag seen between the legs (the transient never dies out inside
a stair). Each up stair is paired with the down leg read at the same command (interpolated, so
the levels need not match): the rotor and a held load cell lag low going up and high coming
down, in proportion to how fast each leg moves, so the two readings weighted by the other
leg's rate cancel the lag to first order (no time column needed; with one, the lag left
between the legs is reported in seconds). The turning stair has no counterpart and is dropped
unless it was held long enough to settle. A pair whose voltages differ by more than
``pair_voltage_rel`` (the battery sagged between the legs) is dropped, and so is a pair where
one leg reads next to nothing (under ``stall_fraction`` of the other above the rest reading: a
rotor that had not started on the way up). ``describe`` says in one line what was kept.

Points where the rotor is stopped (command at the bottom of the scale, or rpm zero where the
log has rpm) read the load cell's offset: tare information, reported. A rotor at rest makes no
thrust, so when a rest plateau measures that offset (``rest_zero``: enough samples, beyond its
own noise) every point of the file is read from it and the rest points, being the zero, are not
map points (the xNova steps file rests at 0.061 N, its sister file at 0.004 N: read raw, the
lower-voltage file seemed to need less throttle at equal thrust, which no motor does). A positive command
that did not turn the rotor (ESC dead band, rotor not started) is not a map point and is dropped;
zero-command points are dropped too with ``drop_tare_points``.
Logs recorded by thrustmap say where each step begins and where the runner saw it settle: those
marks are used instead of being guessed again. Step-summary exports (one averaged row per step)
are steady-state points as they are. ``Points.report`` counts what each rule did.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from thrustmap.core.errors import FitError
from thrustmap.fitting.dataset import SAMPLE_AND_HOLD, STEP_SUMMARY, Dataset, FloatArray

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Selection:
    throttle_range: tuple[float, float] | None = None  # native units, exclusive
    voltage_range: tuple[float, float] | None = None  # V, exclusive
    thrust_range: tuple[float, float] | None = None  # N (after sign normalisation), exclusive;
    # None keeps 0 < T (points without thrust carry no information about producing it)
    all_samples: bool = False
    plateau_tolerance_pct: float = 0.05  # throttle spread still counted as one level (a command)
    min_plateau_samples: int = 4
    settle_sigmas: float = 3.0
    ramp_lag_s: float = 0.1  # assumed rotor + stand lag for the quasi-static test
    lag_budget_pct: float = 0.25  # lag error allowed on ramps, % throttle
    min_ramp_s: float = 2.0  # a run this long (not a step transition) counts as a ramp to pair
    trend_rel: float = 0.005  # a kept plateau may drift this share of its thrust, or its noise
    stall_fraction: float = 0.1  # a staircase leg under this share of the other (above the
    # load cell's rest reading) had a rotor that was not turning: the pair is dropped
    min_stair_legs: int = 3  # stairs in a leg before up/down pairing is tried
    # A staircase whose stairs last fewer sensor updates than this (median) is a quasi-static
    # ramp: too short to drop a transient and still average, so its legs are paired instead.
    quasi_static_updates: float = 8.0
    quasi_static_lags: float = 10.0  # ... or that last less than this many lag time constants
    pair_voltage_rel: float = 0.05  # up/down readings paired only this close in voltage
    # A staircase (up and back down) whose stairs hold at least this many sensor updates after
    # their transient is read as plateaus on each leg, a point per stair, and the legs'
    # disagreement at equal command is measured (it enters the map's interval)
    leg_plateau_updates: int = 5
    # Zero-command points (rotor at rest: thrust is the load cell's offset) are reported as tare
    # information; True also drops them from the map. Off by default for files whose rest reading
    # is not subtracted as the load cell's zero (a step summary's one rest row): there the point
    # stays. Where the zero is subtracted the rest points are always dropped (they are the zero).
    drop_tare_points: bool = False

    def to_dict(self) -> dict[str, Any]:
        return {
            "throttle_range": self.throttle_range,
            "voltage_range": self.voltage_range,
            "thrust_range": self.thrust_range,
            "all_samples": self.all_samples,
            "plateau_tolerance_pct": self.plateau_tolerance_pct,
            "settle_sigmas": self.settle_sigmas,
            "lag_budget_pct": self.lag_budget_pct,
            "trend_rel": self.trend_rel,
            "stall_fraction": self.stall_fraction,
            "quasi_static_updates": self.quasi_static_updates,
            "quasi_static_lags": self.quasi_static_lags,
            "pair_voltage_rel": self.pair_voltage_rel,
            "leg_plateau_updates": self.leg_plateau_updates,
            "drop_tare_points": self.drop_tare_points,
        }


#: per-sample roles (``Points.roles``)
ROLE_OTHER, ROLE_PLATEAU, ROLE_SETTLING, ROLE_STAIR_PAIR, ROLE_RAMP = 0, 1, 2, 3, 4


@dataclass(frozen=True)
class Points:
    """Fit points from one file: plateau means, quasi-static ramp samples, or raw samples."""

    source: str
    thrust_n: FloatArray
    voltage_v: FloatArray
    throttle_pct: FloatArray
    kind: npt.NDArray[np.str_]  # "plateau", "ramp-pair", "ramp", "step-summary" or "sample"
    report: dict[str, Any] = field(default_factory=dict)
    # per SAMPLE of the file (before the range filters): what steady-state extraction did with
    # it (ROLE_* codes); None for step summaries and raw samples
    roles: npt.NDArray[np.int8] | None = None
    # per point: +1 a stair of a staircase's up leg, -1 of its down leg, 0 anything else (None:
    # no staircase read leg by leg)
    leg: npt.NDArray[np.int8] | None = None

    def __len__(self) -> int:
        return len(self.thrust_n)

    @property
    def leg_disagreement_pct(self) -> float:
        """The staircase legs' disagreement at equal thrust, % throttle (95th percentile of the
        up/down pairs; 0 when the file has no staircase read leg by leg)."""
        q = self.report.get("staircase_legs")
        return float(q.get("disagreement_p95_pct", 0.0)) if isinstance(q, dict) else 0.0


def _in_range(x: FloatArray, rng: tuple[float, float] | None) -> npt.NDArray[np.bool_]:
    if rng is None:
        return np.ones(len(x), dtype=bool)
    return np.asarray((x > rng[0]) & (x < rng[1]), dtype=bool)


def select(ds: Dataset, sel: Selection) -> Points:
    """Apply steady-state extraction (unless ``all_samples``) and the range filters."""
    report: dict[str, Any] = {"file": ds.name, "samples": len(ds)}
    roles = None
    leg: npt.NDArray[np.int8] | None = None
    if sel.all_samples:
        t, b, th = ds.thrust_n, ds.voltage_v, ds.throttle_native
        kind = np.full(len(ds), "sample")
    else:
        if ds.meta.get("layout") == STEP_SUMMARY:
            # The stand software already averaged each step: every row is a steady-state point.
            stopped = _rotor_stopped(ds, sel)
            t, b, th = ds.thrust_n, ds.voltage_v, ds.throttle_native
            kind = np.full(len(ds), "step-summary")
            report.update({"layout": STEP_SUMMARY, "step_summary_rows": len(ds)})
        else:
            t, b, th, kind, stopped, info, roles, leg = _steady_state(
                ds, sel, _rotor_stopped(ds, sel)
            )
            report.update(info)
            if "staircase_legs" not in info:
                leg = None
        if stopped.any():
            # The rotor was not turning: the load cell reads its offset (tare information).
            at_zero = stopped & (ds.throttle_scale.to_pct(th) <= sel.plateau_tolerance_pct)
            if at_zero.any():
                report["tare_points"] = int(at_zero.sum()) + report.get("tare_points", 0)
                report["tare_offset_n"] = round(float(np.median(t[at_zero])), 6)
            drop = stopped & ~at_zero  # a command above zero that did not turn the rotor
            if sel.drop_tare_points:
                drop = stopped
            if drop.any():
                report["stopped_rotor_points_dropped"] = int(drop.sum())
                t, b, th, kind = t[~drop], b[~drop], th[~drop], kind[~drop]
                leg = None if leg is None else leg[~drop]
        zero = rest_zero(ds, sel)
        if zero is not None:
            # A rotor at rest makes no thrust: the rest plateau's reading is the load cell's
            # zero, so every point of this file is read from it; the rest points are that zero,
            # not points of the map (at zero thrust any command up to spin-up holds).
            rest = th_pct_le(ds, th, sel) & (kind != "ramp-pair")
            t, b, th, kind = t[~rest] - zero, b[~rest], th[~rest], kind[~rest]
            leg = None if leg is None else leg[~rest]
            report["zero_subtracted_n"] = round(zero, 6)
    # Without an explicit thrust range, points at or below zero thrust (rotor stopped, ESC dead
    # band, load-cell offset) say nothing about producing thrust: drop them, as the paper's 0 < T.
    thrust_rng = sel.thrust_range if sel.thrust_range is not None else (0.0, np.inf)
    keep = (
        _in_range(th, sel.throttle_range)
        & _in_range(b, sel.voltage_range)
        & _in_range(t, thrust_rng)
    )
    report["kept_points"] = int(keep.sum())
    report["dropped_by_range"] = int((~keep).sum())
    stair = report.get("quasi_static_staircase")
    if isinstance(stair, dict) and keep.any() and len(ds):
        # how much of the thrust the file reached the kept points span (from its rest reading)
        zero = report.get("zero_subtracted_n")
        rest = 0.0 if zero is not None else float(report.get("tare_offset_n", 0.0))
        top = float(np.nanmax(ds.thrust_n)) - float(zero if zero is not None else rest)
        if top > 0:
            span = float(t[keep].max()) - max(float(t[keep].min()), rest)
            stair["kept_thrust_n"] = [
                round(float(t[keep].min()), 6),
                round(float(t[keep].max()), 6),
            ]
            stair["thrust_range_kept_pct"] = round(100.0 * span / top, 1)
    return Points(
        source=ds.name,
        thrust_n=t[keep],
        voltage_v=b[keep],
        throttle_pct=ds.throttle_scale.to_pct(th[keep]),
        kind=kind[keep],
        report=report,
        roles=roles,
        leg=None if leg is None else leg[keep],
    )


def describe_legs(legs: dict[str, Any]) -> str:
    """One line on a staircase read leg by leg: its points, the legs' disagreement, a creep."""
    line = (
        f"staircase read leg by leg: {legs.get('legs', 0)} legs, a plateau per stair "
        f"({legs.get('dwell_sensor_updates_settled', 0):g} sensor updates after the transient); "
        f"the legs disagree by {legs.get('disagreement_median_pct', 0.0):.2f} % throttle at equal "
        f"thrust (95th percentile {legs.get('disagreement_p95_pct', 0.0):.2f} %, half of it "
        "carried in the map's interval)"
    )
    creep = legs.get("load_cell_creep")
    if isinstance(creep, dict):
        when = (
            f"{creep['time_s']:g} s" if "time_s" in creep else f"{creep.get('time_rows', 0):g} rows"
        )
        line += (
            f"; a creeping load cell read out first ({100 * creep.get('fraction', 0.0):.0f} % of "
            f"each load change arriving over {when}: the legs disagreed by "
            f"{creep.get('thrust_disagreement_before_median_pct', 0.0):g} % in thrust before)"
        )
    return line


def describe(report: dict[str, Any]) -> str | None:
    """One line on a quasi-static staircase (what was paired and kept), or on a staircase read
    leg by leg, or None."""
    legs = report.get("staircase_legs")
    if isinstance(legs, dict):
        return describe_legs(legs)
    q = report.get("quasi_static_staircase")
    if not isinstance(q, dict):
        n = report.get("quasi_static_legs_unpaired", 0)
        if n:
            return (
                f"quasi-static staircase: {n} leg{'s' if n > 1 else ''} of stairs too short to "
                "settle, with no opposite leg to pair with: the lag cannot be cancelled and "
                "those stairs were dropped (run the staircase up and back down)"
            )
        return None
    if "dwell_s" in q:
        dwell = f"stairs of {q['dwell_s']:.3f} s"
    else:
        dwell = f"stairs of {q.get('dwell_samples', 0):g} samples"
    dwell += f" = {q.get('dwell_sensor_updates', 0):g} sensor updates"
    if "sensor_update_s" in q:
        dwell += f" (one every {q['sensor_update_s']:.3f} s)"
    lag = f", lag between the legs {q['lag_s'] * 1000:.0f} ms" if "lag_s" in q else ""
    kept = ""
    if "kept_thrust_n" in q:
        lo, hi = q["kept_thrust_n"]
        kept = f", kept {lo:.3f}..{hi:.3f} N ({q.get('thrust_range_kept_pct', 0):g} % of the thrust reached)"
    dropped = [
        f"{report[k]} {what}"
        for k, what in (
            ("stair_pairs_dropped_stalled", "with the rotor not turning on one leg"),
            ("stair_pairs_dropped_voltage_apart", "with the legs' voltages apart"),
        )
        if report.get(k)
    ]
    unpaired = report.get("quasi_static_legs_unpaired", 0)
    if unpaired:
        dropped.append(
            f"{unpaired} leg{'s' if unpaired > 1 else ''} without an opposite leg (lag not "
            "cancelled: run the staircase up and back down)"
        )
    return (
        f"quasi-static staircase: {dwell}{lag}; {q.get('legs', 0)} legs paired up/down at equal "
        f"command so the lag cancels: {report.get('stair_pairs', 0)} points{kept}"
        + (f"; dropped {', '.join(dropped)}" if dropped else "")
    )


def th_pct_le(ds: Dataset, th: FloatArray, sel: Selection) -> npt.NDArray[np.bool_]:
    """Points at the zero command (within the plateau tolerance)."""
    return np.asarray(ds.throttle_scale.to_pct(th) <= sel.plateau_tolerance_pct, dtype=bool)


#: the rest plateau's mean is the load cell's zero when it is this many standard errors from 0
ZERO_SIGMAS = 3.0


def rest_zero(ds: Dataset, sel: Selection) -> float | None:
    """The load cell's zero offset measured on the file's rest plateau, or None.

    Samples at the zero command with the rotor stopped read no thrust, so their median is the
    offset every reading of the file carries (a stand tared off-zero, a cell that drifted before
    the sweep). Taken only when it is measured: at least ``min_plateau_samples`` independent rest
    readings (a sample-and-hold load cell's repeats are one reading), and a median beyond
    ``ZERO_SIGMAS`` standard errors of their noise. A step summary's single
    averaged rest row (the stand software tared before the test) has no noise to judge it by
    and is not used."""
    if ds.meta.get("layout") == STEP_SUMMARY:
        return None
    rest = _rotor_stopped(ds, sel) & (ds.throttle_pct <= sel.plateau_tolerance_pct)
    rest &= np.isfinite(ds.thrust_n)
    if not rest.any():
        return None
    # the rest plateau: samples held at one command (not a command passing below the scale)
    level = float(np.median(ds.throttle_pct[rest]))
    rest &= np.abs(ds.throttle_pct - level) <= sel.plateau_tolerance_pct
    t = ds.thrust_n[rest]
    # independent readings: a load cell that holds its value between updates repeats it, so
    # the readings are the changes of value, not the samples
    readings = 1 + int(np.count_nonzero(np.diff(t))) if len(t) else 0
    if readings < sel.min_plateau_samples:
        return None
    zero = float(np.median(t))
    err = float(np.std(t)) / np.sqrt(readings)
    return zero if abs(zero) > ZERO_SIGMAS * err and zero != 0.0 else None


#: a row reading rpm 0 still turns when its thrust stands this share of the file's thrust range
#: above the rest reading (the spin-up measurement's floor, spinup.FLOOR_FRACTION)
MAKING_THRUST_FRACTION = 0.01


def _rotor_stopped(ds: Dataset, sel: Selection) -> npt.NDArray[np.bool_]:
    """Samples with the rotor stopped: a command at the bottom of the scale (within the plateau
    tolerance), or, where the log has rpm that rises above 1000, rpm under 1 % of its maximum
    while the load cell shows no thrust. Their thrust is the load cell's offset, not a point of
    the map. An rpm probe reads 0 below its lowest speed (the RCbenchmark stand's electrical rpm
    at 1050 µs on 2S: 0 rpm, yet 6 gf and 0.38 A against 0.1 A at rest): a row making thrust
    above the rest reading by ``MAKING_THRUST_FRACTION`` of the file's range is turning, as the
    spin-up measurement counts it (thrust OR rpm)."""
    at_bottom = ds.throttle_pct <= sel.plateau_tolerance_pct
    stopped = at_bottom
    if ds.rpm is not None and np.isfinite(ds.rpm).any():
        top = float(np.nanmax(ds.rpm))
        if top > 1000.0:
            no_rpm = np.nan_to_num(ds.rpm, nan=np.inf) < 0.01 * top
            t = ds.thrust_n
            fin = np.isfinite(t)
            rest = at_bottom & fin
            base = float(np.median(t[rest])) if rest.any() else 0.0  # else the stand's tare
            full = float(np.percentile(t[fin], 99)) - base if fin.any() else 0.0
            making = fin & (t - base > MAKING_THRUST_FRACTION * full)
            if not full > 0:
                making[:] = False
            stopped = stopped | (no_rpm & ~making)
    return np.asarray(stopped, dtype=bool)


def plateaus(throttle: FloatArray, tolerance: float) -> list[tuple[int, int]]:
    """Runs [start, end) of consecutive samples within ``tolerance`` of the run's first value."""
    runs: list[tuple[int, int]] = []
    n = len(throttle)
    if n == 0:
        return runs
    # Vectorised: a new run starts where the change from the previous sample exceeds the
    # tolerance; then split runs that drift by more than the tolerance overall (slow ramps).
    starts = np.flatnonzero(np.abs(np.diff(throttle)) > tolerance) + 1
    bounds = np.concatenate([[0], starts, [n]])
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        seg = throttle[a:b]
        if np.ptp(seg) <= tolerance:
            runs.append((int(a), int(b)))
            continue
        s = int(a)
        for i in range(int(a) + 1, int(b)):
            if abs(throttle[i] - throttle[s]) > tolerance:
                runs.append((s, i))
                s = i
        runs.append((s, int(b)))
    return runs


def _ramp_pairs(
    on_ramp: npt.NDArray[np.bool_],
    dth: FloatArray,
    time_s: FloatArray,
    min_samples: int,
    min_ramp_s: float,
) -> list[tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]]:
    """Index arrays of (up-ramp, adjacent down-ramp) runs: contiguous ramp samples moving one way
    for at least ``min_ramp_s`` (the quick transitions between steps are not ramps)."""
    runs: list[tuple[int, npt.NDArray[np.int64]]] = []
    idx = np.flatnonzero(on_ramp)
    if idx.size == 0:
        return []
    direction = np.sign(dth[idx])
    breaks = np.flatnonzero((np.diff(idx) > 1) | (np.diff(direction) != 0)) + 1
    for run in np.split(idx, breaks):
        if len(run) >= min_samples and time_s[run[-1]] - time_s[run[0]] >= min_ramp_s:
            runs.append((int(np.sign(dth[run[0]])), run))
    pairs = []
    for (d1, r1), (d2, r2) in zip(runs, runs[1:], strict=False):
        if d1 > 0 > d2:
            pairs.append((r1, r2))
        elif d1 < 0 < d2:
            pairs.append((r2, r1))
    return pairs


def _levels(ds: Dataset, tol: float) -> list[tuple[int, int, int | None]]:
    """Candidate plateaus [a, b) and, where the recorder marked it, the first settled sample.

    A thrustmap Ds log says which plan step each sample belongs to and where the runner saw the
    level settle: plateaus are the steps' final levels (the start of a step is the slew toward
    it), and settled marks are used as recorded. Other logs: runs of equal throttle."""
    if ds.step is None:
        return [(a, b, None) for a, b in plateaus(ds.throttle_native, tol)]
    out: list[tuple[int, int, int | None]] = []
    step = ds.step
    bounds = np.concatenate([[0], np.flatnonzero(np.diff(step) != 0) + 1, [len(step)]])
    for a0, b0 in zip(bounds[:-1], bounds[1:], strict=True):
        a, b = int(a0), int(b0)
        if step[a] < 0:
            continue  # outside the plan (spin-down after the stop)
        runs = plateaus(ds.throttle_native[a:b], tol)
        ra, rb = runs[-1]  # the level the step holds (a ramp step leaves a short run here)
        a_lvl, b_lvl = a + ra, a + rb
        marks = np.flatnonzero(ds.settled[a_lvl:b_lvl]) if ds.settled is not None else np.array([])
        out.append((a_lvl, b_lvl, a_lvl + int(marks[0]) if marks.size else None))
    return out


def _settle_index(thrust: FloatArray, sigmas: float) -> int:
    """First index from which the thrust stays within the plateau's noise band."""
    n = len(thrust)
    tail = thrust[n // 2 :]
    centre = float(np.median(tail))
    # Noise from successive differences of the tail (robust to a slow drift): MAD / 0.6745 / √2.
    d = np.diff(tail)
    noise = (
        float(np.median(np.abs(d - np.median(d)))) / 0.6745 / np.sqrt(2.0) if len(d) >= 2 else 0.0
    )
    band = sigmas * max(noise, 1e-3 * max(abs(centre), 1e-3), 1e-4)
    outside = np.abs(thrust - centre) > band
    if not outside.any():
        return 0
    last_out = (
        int(np.flatnonzero(outside[: n // 2 + 1]).max()) if outside[: n // 2 + 1].any() else -1
    )
    return last_out + 1


def _settle_index_detrended(y: FloatArray, sigmas: float) -> int:
    """First index from which ``y`` stays within its noise band of the straight line through
    its second half: a stair's transient (rotor lag, a conversion straddling the step), told
    from a slow drift (a creeping load cell) that goes on for the whole stair."""
    n = len(y)
    if n < 4:
        return _settle_index(y, sigmas)
    half = n // 2
    x = np.arange(n, dtype=float)
    slope, icpt = np.polyfit(x[half:], y[half:], 1)
    r = y - (slope * x + icpt)
    d = np.diff(r[half:])
    noise = (
        float(np.median(np.abs(d - np.median(d)))) / 0.6745 / np.sqrt(2.0) if len(d) >= 2 else 0.0
    )
    centre = float(np.median(y[half:]))
    band = sigmas * max(noise, 1e-3 * max(abs(centre), 1e-3), 1e-4)
    outside = np.abs(r[: half + 1]) > band
    return int(np.flatnonzero(outside).max()) + 1 if outside.any() else 0


def _settled_updates(
    thrust: FloatArray, fresh: npt.NDArray[np.bool_], st: _Stair, sigmas: float
) -> npt.NDArray[np.int64]:
    """The samples of a stair that carry a new sensor reading after its transient."""
    upd = st.a + np.flatnonzero(fresh[st.a : st.b])
    if len(upd) < 2:
        return upd[:0]
    return np.asarray(upd[_settle_index_detrended(thrust[upd], sigmas) :], dtype=np.int64)


#: load-cell creep candidates: the share of a load change that arrives late, and its time
#: constant in rows (``_creep_correction``)
CREEP_FRACTIONS = np.linspace(0.0, 0.4, 41)
CREEP_TIME_ROWS = np.geomspace(10.0, 5000.0, 40)
#: a creep correction is applied only when it removes this share of the stairs' drift
CREEP_MIN_GAIN = 0.5
#: candidates whose legs' disagreement is within this factor of the best are equally good
CREEP_NEAR_BEST = 2.0


def _uncreep(
    reading: FloatArray,
    fraction: FloatArray,
    time_rows: FloatArray,
    group: npt.NDArray[np.int64] | None = None,
    groups: int = 0,
) -> tuple[FloatArray, FloatArray]:
    """The load on a creeping load cell from its readings, one column per (fraction, time)
    candidate: reading = F − fraction·(F − S) with S the load through a first-order lag, so
    S follows S' = p·S + q·reading (exact per row), and F = (reading − fraction·S)/(1 − fraction).
    Memory stays bounded by the candidates: returns, per ``group`` of rows (−1: none), the sum
    of F and the sum of |F − reading| (groups × candidates); without groups, F of every row for
    one candidate (``fraction`` and ``time_rows`` of length 1) as the first array."""
    a = np.exp(-1.0 / time_rows)
    p = a - (1.0 - a) * fraction / (1.0 - fraction)
    q = (1.0 - a) / (1.0 - fraction)
    s = np.full(len(fraction), float(reading[0]))
    if group is None:
        out = np.empty(len(reading))
        for k, r in enumerate(reading.tolist()):
            out[k] = float(((r - fraction * s) / (1.0 - fraction))[0])
            s = p * s + q * r
        return out, np.zeros(0)
    sums = np.zeros((groups, len(fraction)))
    change = np.zeros((groups, len(fraction)))
    for k, r in enumerate(reading.tolist()):
        g = int(group[k])
        if g >= 0:
            f = (r - fraction * s) / (1.0 - fraction)
            sums[g] += f
            change[g] += np.abs(f - r)
        s = p * s + q * r
    return sums, change


#: a log longer than this is not searched for creep (time and memory grow with it)
CREEP_MAX_ROWS = 200_000


def _creep_correction(
    thrust: FloatArray,
    pairs: list[tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]],
    voltage_v: FloatArray,
) -> tuple[FloatArray, dict[str, float]] | None:
    """A creeping load cell reads a staircase low on its way up and high on its way down, by
    far more than the rotors lag once a stair has settled. ``pairs``: the settled readings of
    an up stair and of the down stair at the same command (the down stair's thrust scaled by
    (B_up/B_down)², as ω ∝ duty·B and T ∝ ω²: the battery sagged between them). Find the creep
    (the share of a load change that arrives late, and its time constant) that makes the legs
    agree best, and return the file's thrust read through it, with the figures; None when no
    creep removes ``CREEP_MIN_GAIN`` of the legs' disagreement."""
    pairs = [(u, d) for u, d in pairs if len(u) >= 2 and len(d) >= 2]
    if len(pairs) < 3 or len(thrust) > CREEP_MAX_ROWS:
        return None
    ff, tt = np.meshgrid(CREEP_FRACTIONS, CREEP_TIME_ROWS, indexing="ij")
    frac, tau = ff.ravel(), tt.ravel()
    group = np.full(len(thrust), -1, dtype=np.int64)
    sizes = np.zeros(2 * len(pairs))
    for i, (u, d) in enumerate(pairs):
        # a stair may pair with two (equal commands): its rows count for the first pair only
        u, d = u[group[u] < 0], d[group[d] < 0]
        group[u], group[d] = 2 * i, 2 * i + 1
        sizes[2 * i], sizes[2 * i + 1] = len(u), len(d)
    if np.any(sizes < 2):
        return None
    sums, change_sum = _uncreep(thrust, frac, tau, group, 2 * len(pairs))
    means = sums / sizes[:, None]
    cost = np.zeros(len(frac))
    for i, (u, d) in enumerate(pairs):
        scale = (float(np.mean(voltage_v[u])) / float(np.mean(voltage_v[d]))) ** 2
        cost += (means[2 * i] - scale * means[2 * i + 1]) ** 2
    base = int(np.flatnonzero(frac == 0.0)[0])
    # a long slow creep and a shorter one can leave the legs agreeing alike (a slow one reads
    # as a gain): of the candidates that do nearly as well as the best, the smallest correction
    change = change_sum.sum(axis=0) / float(sizes.sum())
    near = cost <= CREEP_NEAR_BEST * float(np.min(cost)) + 1e-300
    best = int(np.flatnonzero(near)[np.argmin(change[near])])
    if frac[best] <= 0.0 or not cost[best] < (1.0 - CREEP_MIN_GAIN) ** 2 * cost[base]:
        return None
    corrected, _ = _uncreep(thrust, frac[best : best + 1], tau[best : best + 1])
    return corrected, {
        "fraction": round(float(frac[best]), 3),
        "time_rows": round(float(tau[best]), 1),
        "legs_disagreement_removed_pct": round(
            100.0 * (1.0 - float(np.sqrt(cost[best] / cost[base]))), 1
        ),
    }


def _legs_disagree(
    command_pct: FloatArray,
    thrust_n: FloatArray,
    voltage_v: FloatArray,
    leg: npt.NDArray[np.int8],
) -> tuple[list[float], list[float]]:
    """The up and down legs' disagreement: at each up point's thrust, the command the down leg
    needed for it minus the up point's (% throttle), and at each up point's command the down
    leg's thrust over the up point's (relative, %). Only where the down leg spans the point.
    The down leg's reading is first carried to the up point's voltage (command × voltage and
    thrust / voltage² hold, as duty × voltage sets speed): a battery that sagged between the
    legs is the map's voltage term, not a disagreement."""
    up, dn = leg > 0, leg < 0
    d_cmd: list[float] = []
    d_thr: list[float] = []
    if up.sum() < 1 or dn.sum() < 2:
        return d_cmd, d_thr
    by_t = np.argsort(thrust_n[dn])
    t_dn, c_dn, v_dn = thrust_n[dn][by_t], command_pct[dn][by_t], voltage_v[dn][by_t]
    by_c = np.argsort(command_pct[dn])
    c_dn2, t_dn2, v_dn2 = command_pct[dn][by_c], thrust_n[dn][by_c], voltage_v[dn][by_c]
    for t, c, v in zip(thrust_n[up], command_pct[up], voltage_v[up], strict=True):
        if t_dn[0] <= t <= t_dn[-1]:
            at_b = float(np.interp(t, t_dn, c_dn)) * float(np.interp(t, t_dn, v_dn)) / float(v)
            d_cmd.append(at_b - float(c))
        if c_dn2[0] <= c <= c_dn2[-1] and t > 0:
            t_b = (
                float(np.interp(c, c_dn2, t_dn2))
                * (float(v) / float(np.interp(c, c_dn2, v_dn2))) ** 2
            )
            d_thr.append(100.0 * (t_b - float(t)) / float(t))
    return d_cmd, d_thr


def _updates(
    thrust: FloatArray, throttle: FloatArray, tol: float, known_held: bool
) -> tuple[npt.NDArray[np.bool_], dict[str, Any]]:
    """Which samples carry a new thrust reading. A sample-and-hold sensor repeats its last
    value exactly until it updates; a continuously sampled one (with noise) practically never
    repeats. Held: more than half the samples exact repeats, and either the loader knows the
    stand's load cell holds (``known_held``) or at least half the value changes happen away
    from command changes, on the sensor's own clock (a log whose thrust only changes with the
    command, exactly constant in between, says nothing about its sensor)."""
    n = len(thrust)
    fresh = np.ones(n, dtype=bool)
    if n < 8:
        return fresh, {}
    repeat = np.diff(thrust) == 0
    if float(repeat.mean()) <= 0.5:
        return fresh, {}
    changes = np.flatnonzero(~repeat) + 1
    if not known_held:
        cmd = np.flatnonzero(np.abs(np.diff(throttle)) > tol) + 1
        near_cmd = np.zeros(n, dtype=bool)
        for d in (-2, -1, 0, 1, 2):  # a change within two samples of a command change
            near_cmd[np.clip(cmd + d, 0, n - 1)] = True
        own_clock = int((~near_cmd[changes]).sum())
        if len(changes) < 3 or own_clock < 0.5 * len(changes):
            return fresh, {}
    fresh[1:] = ~repeat
    updates = int(fresh.sum())
    return fresh, {
        "sample_and_hold_sensor": True,
        "thrust_updates": updates,
        "samples_per_update": round(n / max(updates, 1), 1),
    }


def _trends(y: FloatArray, sel: Selection) -> bool:
    """The kept part of a plateau still trends: its two halves' means differ by more than 4
    standard errors of the (successive-difference) noise and more than ``trend_rel``."""
    n = len(y)
    if n < 6:
        return False
    half = n // 2
    d = np.diff(y)
    noise = float(np.median(np.abs(d - np.median(d)))) / 0.6745 / np.sqrt(2.0)
    drift = abs(float(np.mean(y[:half]) - np.mean(y[n - half :])))
    floor = max(sel.trend_rel * abs(float(np.median(y))), 1e-3)
    return bool(drift > max(4.0 * noise * np.sqrt(2.0 / half), floor))


@dataclass(frozen=True)
class _Stair:
    """One command level: [a, b), its command, row-mean thrust and voltage, fresh updates and
    dwell (s when the log has time, else rows)."""

    a: int
    b: int
    command: float
    thrust_n: float
    voltage_v: float
    updates: int
    dwell: float


def _stair_legs(stairs: list[_Stair], tol: float, min_legs: int) -> list[tuple[int, list[int]]]:
    """Monotone runs of contiguous stairs (direction, stair indices), at least ``min_legs``
    long; adjacent legs share their turning stair."""
    legs: list[tuple[int, list[int]]] = []
    for i in range(1, len(stairs)):
        step = stairs[i].command - stairs[i - 1].command
        d = 0 if abs(step) <= tol else (1 if step > 0 else -1)
        contiguous = stairs[i].a <= stairs[i - 1].b
        if d and contiguous and legs and legs[-1][0] == d and legs[-1][1][-1] == i - 1:
            legs[-1][1].append(i)
        elif d and contiguous:
            legs.append((d, [i - 1, i]))
    return [(d, leg) for d, leg in legs if len(leg) >= min_legs]


def _leg_rate(stairs: list[_Stair], leg: list[int]) -> float:
    """How fast a leg moves: median command step over median dwell (per s, or per row)."""
    steps = [abs(stairs[j].command - stairs[i].command) for i, j in zip(leg, leg[1:], strict=False)]
    dwell = float(np.median([stairs[i].dwell for i in leg[1:-1] or leg]))
    return float(np.median(steps)) / max(dwell, 1e-9)


@dataclass
class _Paired:
    """Up/down leg pairs at equal command: points and what the pairing saw."""

    thrust_n: list[float] = field(default_factory=list)
    voltage_v: list[float] = field(default_factory=list)
    command: list[float] = field(default_factory=list)
    stairs: list[tuple[int, int]] = field(default_factory=list)  # (up stair, down stair near)
    used: set[int] = field(default_factory=set)
    stalled: int = 0
    voltage_apart: int = 0
    lag_s: list[float] = field(default_factory=list)


def _pair_legs(
    stairs: list[_Stair],
    up: list[int],
    down: list[int],
    turn: int,
    rest_n: float,
    sel: Selection,
    at_rest: npt.NDArray[np.bool_],
) -> _Paired:
    """Pair each up-leg stair with the adjacent down leg read at the same command.

    Rotor and load cell lag low on the way up and high on the way down. With a first-order lag
    the error is proportional to how fast the leg moves, so the two readings are weighted by the
    other leg's rate (equal rates: the plain mean) and the lag cancels to first order. The down
    leg is interpolated at the up stair's command (its levels need not match); the turning stair
    has no counterpart and is not paired with itself. The down leg is later, so the battery has
    sagged further: a pair whose voltages differ by more than ``pair_voltage_rel`` is dropped.
    The lag left between the legs is reported (s, when the log has time)."""
    out = _Paired()
    for _ in (0,):
        up_i = [i for i in up if i != turn]
        down_i = sorted((i for i in down if i != turn), key=lambda i: stairs[i].command)
        if len(down_i) < 2 or not up_i:
            break
        dc = np.array([stairs[i].command for i in down_i])
        dt = np.array([stairs[i].thrust_n for i in down_i])
        dv = np.array([stairs[i].voltage_v for i in down_i])
        r_up, r_dn = _leg_rate(stairs, up), _leg_rate(stairs, down)
        w_up = r_dn / (r_up + r_dn) if r_up + r_dn > 0 else 0.5
        uc = np.array([stairs[i].command for i in up_i])
        ut = np.array([stairs[i].thrust_n for i in up_i])
        slope = np.gradient(ut, uc) if len(up_i) >= 2 else np.zeros(len(up_i))  # dT/dcommand
        for k, u in enumerate(up_i):
            c = stairs[u].command
            if c < dc[0] - 1e-9 or c > dc[-1] + 1e-9:
                continue
            out.used.add(u)
            t_dn = float(np.interp(c, dc, dt))
            v_dn = float(np.interp(c, dc, dv))
            lo, hi = sorted((stairs[u].thrust_n - rest_n, t_dn - rest_n))
            # (a rotor the log shows stopped is kept here: select() drops it, saying why)
            if not at_rest[u] and (hi <= 0 or lo <= sel.stall_fraction * hi):
                out.stalled += 1
                continue
            v_up = stairs[u].voltage_v
            if abs(v_up - v_dn) > sel.pair_voltage_rel * 0.5 * (v_up + v_dn):
                out.voltage_apart += 1
                continue
            out.thrust_n.append(w_up * stairs[u].thrust_n + (1.0 - w_up) * t_dn)
            out.voltage_v.append(w_up * v_up + (1.0 - w_up) * v_dn)
            out.command.append(c)
            near = down_i[int(np.argmin(np.abs(dc - c)))]
            out.stairs.append((u, near))
            if slope[k] > 0:  # T_dn - T_up = tau * dT/dc * (rate_up + rate_down)
                out.lag_s.append((t_dn - stairs[u].thrust_n) / (slope[k] * (r_up + r_dn)))
        out.used.update(i for i in down_i if dc[0] <= stairs[i].command <= dc[-1])
    return out


def _row_period(ds: Dataset) -> float:
    """The log's median sample period (s), 0 without time."""
    if ds.time_s is None or len(ds) < 2:
        return 0.0
    d = np.diff(ds.time_s)
    d = d[d > 0]
    return float(np.median(d)) if d.size else 0.0


def _steady_state(
    ds: Dataset, sel: Selection, stopped: npt.NDArray[np.bool_]
) -> tuple[
    FloatArray,
    FloatArray,
    FloatArray,
    np.ndarray[Any, Any],
    npt.NDArray[np.bool_],
    dict[str, Any],
    npt.NDArray[np.int8],
    npt.NDArray[np.int8],
]:
    """Points, their kinds, whether each was taken with the rotor mostly stopped, a report, and
    each sample's role."""
    th = ds.throttle_native
    tol = sel.plateau_tolerance_pct / 100.0 * ds.throttle_scale.span
    known = ds.meta.get("thrust_sensor") == SAMPLE_AND_HOLD
    fresh, held = _updates(ds.thrust_n, th, tol, known)
    t_out: list[float] = []
    b_out: list[float] = []
    th_out: list[float] = []
    kinds: list[str] = []
    point_at_rest: list[bool] = []  # per point: most of its samples had the rotor stopped
    n_plateau_samples = n_settle_dropped = n_ramp_kept = 0
    n_runner_settled = n_trending = n_unsettled = 0
    in_plateau = np.zeros(len(ds), dtype=bool)
    roles = np.zeros(len(ds), dtype=np.int8)
    levels = _levels(ds, tol)
    # per-level sums from cumulative sums: one pass, however many levels a file has
    period = _row_period(ds)
    bounds = np.array([(a, b) for a, b, _ in levels], dtype=np.int64).reshape(-1, 2)
    lo_i, hi_i = bounds[:, 0], bounds[:, 1]
    rows_n = np.maximum(hi_i - lo_i, 1)

    def level_mean(x: npt.ArrayLike) -> FloatArray:
        c = np.concatenate([[0.0], np.cumsum(np.asarray(x, dtype=float))])
        return np.asarray((c[hi_i] - c[lo_i]) / rows_n, dtype=float)

    cmd_m, t_m, v_m = level_mean(th), level_mean(ds.thrust_n), level_mean(ds.voltage_v)
    n_upd = level_mean(fresh) * rows_n
    if ds.time_s is not None and len(levels):
        dwells = ds.time_s[hi_i - 1] - ds.time_s[lo_i] + period
    else:
        dwells = (hi_i - lo_i).astype(float)
    stairs = [
        _Stair(
            a=int(lo_i[k]),
            b=int(hi_i[k]),
            command=float(cmd_m[k]),
            # row mean of what the sensor showed (a held reading counts for as long as it held)
            thrust_n=float(t_m[k]),
            voltage_v=float(v_m[k]),
            updates=int(round(n_upd[k])),
            dwell=float(dwells[k]),
        )
        for k in range(len(levels))
    ]
    at_rest_n = [
        st.thrust_n
        for st in stairs
        if ds.throttle_scale.to_pct(st.command) <= sel.plateau_tolerance_pct
    ]
    rest_n = float(np.median(at_rest_n)) if at_rest_n else 0.0
    # Quasi-static staircases: legs whose stairs last only a few sensor updates (too short to
    # settle and average) are a slow ramp seen through the sensor: pair up and down legs.
    candidates = [i for i, st in enumerate(stairs) if st.b - st.a >= 2]
    sub = [stairs[i] for i in candidates]
    # A leg pair is quasi-static when its stairs last fewer sensor updates than
    # ``quasi_static_updates`` or less than ``quasi_static_lags`` times the lag seen between its
    # legs (rotor + sensor): the transient never dies out inside a stair.
    all_legs = _stair_legs(sub, tol, sel.min_stair_legs)
    sub_at_rest = np.array([bool(stopped[st.a : st.b].mean() > 0.5) for st in sub], dtype=bool)
    legpairs = _Paired()
    legs: list[list[int]] = []
    lags: list[float] = []
    n_turns = 0
    # staircases whose stairs hold long enough after their transient: a plateau on each leg
    legged: list[tuple[list[int], list[int], int]] = []
    settled: dict[int, npt.NDArray[np.int64]] = {}
    for (d1, l1), (d2, l2) in zip(all_legs, all_legs[1:], strict=False):
        if d1 == d2 or l2[0] - l1[-1] > 1:
            continue
        up_leg, down_leg = (l1, l2) if d1 > 0 else (l2, l1)
        for i in up_leg + down_leg:
            if i not in settled:
                settled[i] = _settled_updates(ds.thrust_n, fresh, sub[i], sel.settle_sigmas)
        held_for = [len(settled[i]) for i in up_leg + down_leg if i != l1[-1]]
        if held_for and float(np.median(held_for)) >= sel.leg_plateau_updates:
            legged.append((up_leg, down_leg, l1[-1]))
            continue
        one = _pair_legs(sub, up_leg, down_leg, l1[-1], rest_n, sel, sub_at_rest)
        both = up_leg + down_leg
        updates = float(np.median([sub[i].updates for i in both]))
        dwell = float(np.median([sub[i].dwell for i in both]))
        lag = float(np.median(one.lag_s)) if one.lag_s else 0.0
        row_lag = lag if ds.time_s is not None else 0.0
        if updates >= sel.quasi_static_updates and not dwell < sel.quasi_static_lags * row_lag:
            continue
        legs += [up_leg, down_leg]
        turn = sub[l1[-1]]
        if turn.updates < sel.quasi_static_updates or turn.dwell < sel.quasi_static_lags * row_lag:
            # the turning stair has no counterpart and too short a hold to settle: unsettled
            one.used.add(l1[-1])
            n_turns += 1
        lags += one.lag_s
        legpairs.thrust_n += one.thrust_n
        legpairs.voltage_v += one.voltage_v
        legpairs.command += one.command
        legpairs.stairs += one.stairs
        legpairs.used |= one.used
        legpairs.stalled += one.stalled
        legpairs.voltage_apart += one.voltage_apart
    legpairs.lag_s = lags
    paired_starts = {leg[0] for leg in legs}
    # legs of a staircase too short to settle that had no opposite leg to pair with: their lag
    # cannot be cancelled (run the staircase up and back down)
    n_unpaired = sum(
        1
        for _, leg in all_legs
        if leg[0] not in paired_starts
        and float(np.median([sub[i].updates for i in leg])) < sel.quasi_static_updates
    )
    used = {candidates[i] for i in legpairs.used}
    for (u, w), t, v, c in zip(
        legpairs.stairs, legpairs.thrust_n, legpairs.voltage_v, legpairs.command, strict=True
    ):
        t_out.append(t)
        b_out.append(v)
        th_out.append(c)
        kinds.append("stair-pair")
        su, sw = sub[u], sub[w]
        rows = np.r_[su.a : su.b, sw.a : sw.b]
        point_at_rest.append(bool(stopped[rows].mean() > 0.5))
        roles[rows] = ROLE_STAIR_PAIR
    for i in used:
        in_plateau[stairs[i].a : stairs[i].b] = True
    n_stair_samples = sum(stairs[i].b - stairs[i].a for i in used)
    n_stair_pairs = len(legpairs.thrust_n)
    staircase: dict[str, Any] = {}
    if legs:
        leg_stairs = [sub[i] for leg in legs for i in leg]
        dwell = float(np.median([st.dwell for st in leg_stairs]))
        per_update = len(ds) / max(int(fresh.sum()), 1)
        staircase = {
            "dwell_s" if ds.time_s is not None else "dwell_samples": round(dwell, 4),
            "dwell_sensor_updates": round(float(np.median([st.updates for st in leg_stairs])), 1),
            "legs": len(legs),
        }
        if ds.time_s is not None:
            staircase["sensor_update_s"] = round(per_update * period, 4)
        if legpairs.lag_s and ds.time_s is not None:
            # rotor + sensor lag seen between the legs (a first-order time constant)
            staircase["lag_s"] = round(float(np.median(legpairs.lag_s)), 4)
    # staircases read leg by leg: a plateau per stair (its transient dropped, the rest averaged,
    # a drift kept: it is what the legs' disagreement measures), the turning stair once
    leg_of: list[int] = [0] * len(t_out)
    d_cmd_all: list[float] = []
    d_thr_all: list[float] = []
    held_updates: list[int] = []
    reading = ds.thrust_n
    creep: dict[str, float] = {}
    if legged:
        same_command: list[tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]] = []
        for up_leg, down_leg, turn_i in legged:
            for u in up_leg:
                if u == turn_i:
                    continue  # (the rest stairs at both ends pair too: unloaded, equal)
                for d in down_leg:
                    if d != turn_i and abs(sub[d].command - sub[u].command) <= tol:
                        same_command.append((settled[u], settled[d]))
        found = _creep_correction(ds.thrust_n, same_command, ds.voltage_v)
        if found is not None:
            reading, creep = found
            if period > 0:
                creep["time_s"] = round(creep["time_rows"] * period, 3)
    raw_of: list[float] = []  # the legged points' thrust as read (before any creep correction)
    d_thr_raw: list[float] = []
    for up_leg, down_leg, turn_i in legged:
        first = len(t_out)
        for i, sign in [(i, 1) for i in up_leg] + [(i, -1) for i in down_leg if i != turn_i]:
            li = candidates[i]
            if li in used:
                continue
            st = sub[i]
            kept = settled[i]
            used.add(li)
            in_plateau[st.a : st.b] = True
            if len(kept) < 2:
                n_unsettled += 1
                continue
            start = int(kept[0])
            held_updates.append(len(kept))
            n_plateau_samples += st.b - st.a
            n_settle_dropped += start - st.a
            roles[st.a : start] = ROLE_SETTLING
            roles[start : st.b] = ROLE_PLATEAU
            t_out.append(float(np.mean(reading[kept])))
            raw_of.append(float(np.mean(ds.thrust_n[kept])))
            b_out.append(float(np.mean(ds.voltage_v[start : st.b])))
            th_out.append(float(np.mean(th[start : st.b])))
            kinds.append("plateau")
            point_at_rest.append(bool(stopped[start : st.b].mean() > 0.5))
            leg_of.append(0 if i == turn_i else sign)
        mine = np.asarray(leg_of[first:], dtype=np.int8)
        moving = ~np.asarray(point_at_rest[first:], dtype=bool)
        dc, dt_rel = _legs_disagree(
            np.asarray(ds.throttle_scale.to_pct(np.asarray(th_out[first:])))[moving],
            np.asarray(t_out[first:])[moving],
            np.asarray(b_out[first:])[moving],
            mine[moving],
        )
        d_cmd_all += dc
        d_thr_all += dt_rel
        d_thr_raw += _legs_disagree(
            np.asarray(ds.throttle_scale.to_pct(np.asarray(th_out[first:])))[moving],
            np.asarray(raw_of[len(raw_of) - len(mine) :])[moving],
            np.asarray(b_out[first:])[moving],
            mine[moving],
        )[1]
    for li, (a, b, settled_from) in enumerate(levels):
        if li in used:
            continue
        upd = a + np.flatnonzero(fresh[a:b])  # samples with a new thrust reading
        if len(upd) < sel.min_plateau_samples:
            continue
        in_plateau[a:b] = True
        if settled_from is not None:
            start = settled_from  # the recorder saw it settled from here: no guessing
            n_runner_settled += 1
        else:
            k = _settle_index(ds.thrust_n[upd], sel.settle_sigmas)
            start = int(upd[k]) if k < len(upd) else b
        kept = upd[upd >= start]
        if len(kept) < 2:
            n_unsettled += 1
            continue
        if _trends(ds.thrust_n[kept], sel):
            n_trending += 1
            continue
        n_plateau_samples += b - a
        n_settle_dropped += start - a
        roles[a:start] = ROLE_SETTLING
        roles[start:b] = ROLE_PLATEAU
        t_out.append(float(np.mean(ds.thrust_n[kept])))
        b_out.append(float(np.mean(ds.voltage_v[start:b])))
        th_out.append(float(np.mean(th[start:b])))
        kinds.append("plateau")
        point_at_rest.append(bool(stopped[start:b].mean() > 0.5))
    n_stalled = legpairs.stalled
    # Ramps: pair each up-ramp with the down-ramp next to it (at the same throttle the rotor
    # lags below on the way up and above on the way down, so the mean cancels the lag to first
    # order); keep unpaired ramp samples only where the slew makes lag cheaper than the budget.
    n_paired = 0
    if ds.time_s is not None and len(ds) > 2:
        dt = np.gradient(ds.time_s)
        ok_dt = dt > 0
        dth = np.gradient(ds.throttle_pct)
        slew_pct_s = np.full(len(ds), np.inf)
        slew_pct_s[ok_dt] = np.abs(dth[ok_dt] / dt[ok_dt])
        on_ramp = (~in_plateau) & ok_dt & (slew_pct_s > 0) & np.isfinite(slew_pct_s)
        paired = np.zeros(len(ds), dtype=bool)
        for up, down in _ramp_pairs(
            on_ramp, dth, ds.time_s, sel.min_plateau_samples, sel.min_ramp_s
        ):
            x_up, x_dn = th[up], th[down]
            order = np.argsort(x_dn)
            inside = (x_up >= x_dn.min()) & (x_up <= x_dn.max())
            if inside.sum() < 2:
                continue
            for arr, out in ((ds.thrust_n, t_out), (ds.voltage_v, b_out)):
                other = np.interp(x_up[inside], x_dn[order], arr[down][order])
                out.extend(((arr[up][inside] + other) / 2.0).tolist())
            th_out.extend(x_up[inside].tolist())
            kinds.extend(["ramp-pair"] * int(inside.sum()))
            point_at_rest.extend(stopped[up[inside]].tolist())
            n_paired += int(inside.sum())
            paired[up[inside]] = True
            paired[down] = True
            roles[up[inside]] = ROLE_RAMP
            roles[down] = ROLE_RAMP
        quasi = on_ramp & ~paired & (slew_pct_s * sel.ramp_lag_s <= sel.lag_budget_pct)
        idx = np.flatnonzero(quasi)
        roles[idx] = ROLE_RAMP
        n_ramp_kept = len(idx) + int(paired.sum())
        t_out.extend(ds.thrust_n[idx].tolist())
        b_out.extend(ds.voltage_v[idx].tolist())
        th_out.extend(th[idx].tolist())
        kinds.extend(["ramp"] * len(idx))
        point_at_rest.extend(stopped[idx].tolist())
    leg_of += [0] * (len(t_out) - len(leg_of))
    if not t_out:
        why = (
            f"; {n_unpaired} staircase leg{'s' if n_unpaired > 1 else ''} of stairs too short to "
            "settle had no opposite leg to cancel the lag (run it up and back down)"
            if n_unpaired
            else ""
        )
        raise FitError(
            "no steady-state points found (no throttle plateau of "
            f"{sel.min_plateau_samples}+ samples, no slow ramp{why}); use --all-samples to fit "
            "raw samples",
            file=ds.path,
        )
    info = {
        "plateaus": kinds.count("plateau"),
        "plateaus_settled_by_recorder": n_runner_settled,
        "plateau_samples": n_plateau_samples,
        "settling_samples_dropped": n_settle_dropped,
        "ramp_samples_kept": n_ramp_kept,
        "ramp_pair_points": n_paired,
        "stair_pair_samples": n_stair_samples,
        "transient_samples_dropped": len(ds) - n_plateau_samples - n_ramp_kept - n_stair_samples,
        **held,
    }
    rules = {
        "plateaus_dropped_still_trending": n_trending,
        "plateaus_dropped_unsettled": n_unsettled,
        "stair_pairs": n_stair_pairs,
        "stair_pairs_dropped_stalled": n_stalled,
        "stair_pairs_dropped_voltage_apart": legpairs.voltage_apart,
        "turning_stairs_dropped_unsettled": n_turns,
        "quasi_static_legs_unpaired": n_unpaired,
    }
    info.update({k: v for k, v in rules.items() if v})
    if staircase:
        info["quasi_static_staircase"] = staircase
    if legged:
        abs_cmd = np.abs(np.asarray(d_cmd_all, dtype=float))
        info["staircase_legs"] = {
            "legs": 2 * len(legged),
            "dwell_sensor_updates_settled": round(float(np.median(held_updates)), 1)
            if held_updates
            else 0.0,
            "up_down_pairs": len(d_cmd_all),
            # down leg minus up leg: at equal thrust in % throttle, at equal command in % thrust
            "disagreement_median_pct": round(float(np.median(abs_cmd)), 4) if len(abs_cmd) else 0.0,
            "disagreement_p95_pct": round(float(np.percentile(abs_cmd, 95)), 4)
            if len(abs_cmd)
            else 0.0,
            "thrust_disagreement_median_pct": round(float(np.median(d_thr_all)), 2)
            if d_thr_all
            else 0.0,
        }
        if creep:
            creep["thrust_disagreement_before_median_pct"] = (
                round(float(np.median(d_thr_raw)), 2) if d_thr_raw else 0.0
            )
            info["staircase_legs"]["load_cell_creep"] = creep
    short_rest = [
        st
        for i, st in enumerate(stairs)
        if i not in used
        and st.updates < sel.min_plateau_samples
        and ds.throttle_scale.to_pct(st.command) <= sel.plateau_tolerance_pct
    ]
    if short_rest:  # zero-command stairs too short to be points: still the rest reading
        info["tare_points"] = len(short_rest)
        info["tare_offset_n"] = round(rest_n, 6)
    return (
        np.asarray(t_out),
        np.asarray(b_out),
        np.asarray(th_out),
        np.asarray(kinds),
        np.asarray(point_at_rest, dtype=bool),
        info,
        roles,
        np.asarray(leg_of, dtype=np.int8),
    )
