"""Df: the flight samples the correction factor is fitted on (seed paper section 3.4).

From each flight log keep the samples where the paper's assumptions hold: armed and airborne,
away from takeoff/landing transients, near hover (upward specific force close to g, small tilt).
All streams are resampled onto one timeline (bin means at ``rate_hz``; a stream with no sample
within ``max_gap_s`` of a bin leaves it empty). Then:

- F_m = m · a_up (collective, N; mass from the user).
- T_c (collective, N) from the log's thrust command in newtons when it has one, otherwise from the
  motor outputs pushed through the stand map's forward direction, per rotor, summed over rotors
  (the stand map is per rotor). A normalised collective command is kept as ``thrust_cmd_norm``.

``extract()`` returns the table and a report of how much flight time each filter dropped and
why; ``write_df()`` writes the CSV plus a JSON sidecar naming the origin of every column.
"""

from __future__ import annotations

import csv
import io
import json
import logging
import warnings as _warnings
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from thrustmap.core.errors import ConfigError, DataFormatError
from thrustmap.core.files import atomic_write_text
from thrustmap.core.jsonfile import load_json
from thrustmap.core.units import ThrottleScale
from thrustmap.fitting.flightlogs.series import (
    FlightLog,
    FloatArray,
    Signal,
    nanmedian,
    refuse_unphysical_specific_force,
    specific_force_unit,
)

if TYPE_CHECKING:  # pandas is imported where a table is asked for: `flightlog extract` runs
    import pandas as pd  # without it (its import alone took 0.3 s of a 0.7 s extraction)

    from thrustmap.fitting.mapfile import ThrustMap

log = logging.getLogger(__name__)

G0 = 9.80665
#: an altitude signal whose 5-95 % spread exceeds this while standing on the ground is not used
GROUND_HEIGHT_SPREAD_M = 3.0
#: a range sensor judges height when it is valid for at least this share of the airborne time
RANGE_COVERAGE = 0.8
#: an accelerometer logged slower than this aliases vibration into a_up (the report says so)
MIN_ACCEL_RATE_HZ = 20.0
#: fewer Df samples than this are too few for a γ fit (the report says why)
MIN_DF_SAMPLES = 50
#: a command at or above this fraction of full scale is saturated (thrust limited)
SATURATED_NORM = 0.98
DF_FORMAT = "thrustmap.df"
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class DfOptions:
    mass_kg: float | None = None  # None: use the log's own mass (seed-paper CSV) if it has one
    rotors: int | None = None  # None: number of motor-output columns
    rate_hz: float = 10.0
    accel_tol_mps2: float = 1.0  # keep |a_up − g| ≤ this (bin-averaged)
    tilt_max_deg: float = 15.0
    settle_s: float = 2.0  # dropped after takeoff and before landing
    max_gap_s: float = 1.0
    steady_tol: float = 0.15  # keep |cmd − running median| ≤ this fraction of the median
    steady_window_s: float = 5.0  # longer than a command dip (≤ 1.5 s seen) twice over
    accel_smooth_s: float = 0.5  # centred running mean of a_up (IMU vibration, aliasing)
    min_height_m: float = 0.5  # airborne only this far above the takeoff level (spool-up, ramp)
    climb_max_mps: float = 1.0  # keep |climb rate| ≤ this (takeoff ramp, climbs, descents)
    liftoff_frac: float = 0.9  # airborne from when the command first reaches this × hover
    thrust_source: str = "auto"  # auto | log (thrust_cmd_n) | motors | norm
    # supported on the ground: the command below this × hover while a_up stays at g ...
    ground_cmd_frac: float = 0.7
    ground_min_s: float = 2.0  # ... (or the altitude back at the ground level) this long
    height_window_s: float = 5.0  # takeoff level judged this near takeoff, landing level landing
    level_disagree_m: float = 1.0  # warn when takeoff and landing levels differ by more
    rotor_lag_s: float = 0.1  # drop this near a command change larger than steady_tol

    def __post_init__(self) -> None:
        if self.mass_kg is not None and not self.mass_kg > 0:
            raise ConfigError(f"mass must be positive, got {self.mass_kg} kg")
        if self.rotors is not None and self.rotors < 1:
            raise ConfigError(f"rotor count must be at least 1, got {self.rotors}")
        if not self.rate_hz > 0:
            raise ConfigError(f"resampling rate must be positive, got {self.rate_hz} Hz")
        for name, value, lo, hi in (  # issue 31: each filter a band it can be (lo < value <= hi)
            ("--accel-tol", self.accel_tol_mps2, 0.0, 9.80665),
            ("--tilt-max-deg", self.tilt_max_deg, 0.0, 90.0),
            ("--climb-max", self.climb_max_mps, 0.0, 100.0),
            ("--settle-s", self.settle_s, -1e-12, 3600.0),
            ("--min-height-m", self.min_height_m, -1e-12, 1000.0),
        ):
            if not lo < value <= hi:  # also NaN
                raise ConfigError(f"{name} {value:g}: expected {max(lo, 0):g}..{hi:g}")
        if self.thrust_source not in ("auto", "log", "motors", "norm"):
            raise ConfigError(
                f"thrust source '{self.thrust_source}': expected auto, log, motors or norm"
            )


@dataclass
class FilterStep:
    name: str
    reason: str
    dropped_s: float
    remaining_s: float


@dataclass
class FlightReport:
    flight: str
    path: str
    format: str
    duration_s: float
    kept_s: float
    samples: int
    steps: list[FilterStep] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    voltage_unknown: str | None = None  # why the Df has no battery voltage (None: it has one)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


Columns = dict[str, npt.NDArray[Any]]


class Df:
    """The Df table, its sidecar (``sources``) and the per-flight reports.

    ``table`` is a pandas DataFrame, built from the extracted columns on first use (the
    extraction itself and ``write_df`` need no pandas); ``Df(table, sources, reports)``
    still takes a DataFrame."""

    def __init__(
        self,
        table: pd.DataFrame | None = None,
        sources: dict[str, Any] | None = None,
        reports: list[FlightReport] | None = None,
        *,
        columns: Columns | None = None,
    ) -> None:
        self._table = table
        self._columns = columns
        self.sources: dict[str, Any] = sources if sources is not None else {}
        self.reports: list[FlightReport] = reports if reports is not None else []

    @property
    def table(self) -> pd.DataFrame:
        if self._table is None:
            import pandas as pd

            self._table = pd.DataFrame(self._columns or {})
            self._columns = None
        return self._table

    @table.setter
    def table(self, value: pd.DataFrame) -> None:
        self._table, self._columns = value, None

    def column(self, name: str) -> npt.NDArray[Any]:
        """One column as a numpy array, without building the pandas table (KeyError when the
        Df has no such column)."""
        if self._table is not None:
            return np.asarray(self._table[name].to_numpy())
        return np.asarray((self._columns or {})[name])

    def __len__(self) -> int:
        if self._table is not None:
            return len(self._table)
        cols = self._columns or {}
        return len(next(iter(cols.values()))) if cols else 0

    def __repr__(self) -> str:
        return f"Df({len(self)} samples, {len(self.reports)} flight(s))"


# -- resampling ----------------------------------------------------------------------------------


def _bin_mean(sig: Signal, t0: float, rate_hz: float, nbins: int, max_gap_s: float) -> FloatArray:
    """Mean of the samples in each bin; bins without samples interpolate when data is near."""
    centres = t0 + (np.arange(nbins) + 0.5) / rate_hz
    vals = sig.values if sig.values.ndim == 2 else sig.values[:, None]
    out = np.full((nbins, vals.shape[1]), np.nan)
    b = np.floor((sig.time_s - t0) * rate_hz).astype(np.int64)
    inside = (b >= 0) & (b < nbins)
    for k in range(vals.shape[1]):
        v = vals[:, k]
        ok = inside & np.isfinite(v)
        cnt = np.bincount(b[ok], minlength=nbins)
        tot = np.bincount(b[ok], weights=v[ok], minlength=nbins)
        col = np.where(cnt > 0, tot / np.maximum(cnt, 1), np.nan)
        fin = np.isfinite(v)
        if fin.sum() >= 1:
            ts, vs = sig.time_s[fin], v[fin]
            if len(ts) == 1:  # one sample: its distance to every bin centre
                near = np.abs(ts[0] - centres)
            else:
                idx = np.clip(np.searchsorted(ts, centres), 1, len(ts) - 1)
                near = np.minimum(np.abs(ts[idx] - centres), np.abs(ts[idx - 1] - centres))
            interp = np.interp(centres, ts, vs)
            col = np.where(np.isnan(col) & (near <= max_gap_s), interp, col)
        out[:, k] = col
    return out if sig.values.ndim == 2 else out[:, 0]


def _windows(x: FloatArray, window: int) -> FloatArray:
    """Centred windows of ``window`` bins (NaN beyond the ends), one row per bin; the same
    alignment as pandas' ``rolling(window, center=True)``."""
    before = window // 2
    padded = np.concatenate([np.full(before, np.nan), x, np.full(window - 1 - before, np.nan)])
    return np.lib.stride_tricks.sliding_window_view(padded, window)


def _running_median(x: FloatArray, window: int) -> FloatArray:
    """Centred running median over ``window`` bins, NaN-aware (NaN only where all are)."""
    window = max(window, 1)
    if window == 1:
        return np.asarray(x, float)
    out = np.full(len(x), np.nan)
    views = _windows(np.asarray(x, float), window)  # a view: no copy
    step = max(1, 2_000_000 // window)  # nanmedian copies: bounded chunks
    with _warnings.catch_warnings():
        _warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN windows stay NaN
        for a in range(0, len(x), step):
            out[a : a + step] = nanmedian(views[a : a + step], axis=1)
    return out


def _steady(cmd: FloatArray, window: int, tol: float) -> BoolArray:
    """True where the command is within ``tol`` (relative) of its centred running median."""
    med = _running_median(np.asarray(cmd, float), window)
    with np.errstate(invalid="ignore"):
        return np.asarray(np.abs(cmd - med) <= tol * np.abs(med))


def _smooth(x: FloatArray, window: int) -> FloatArray:
    """Centred running mean (NaN-aware) over ``window`` bins."""
    if window <= 1:
        return x
    before = window // 2
    fin = np.isfinite(x)
    v = np.concatenate([[0.0], np.cumsum(np.where(fin, x, 0.0))])
    c = np.concatenate([[0], np.cumsum(fin.astype(np.int64))])
    idx = np.arange(len(x))
    lo = np.clip(idx - before, 0, len(x))
    hi = np.clip(idx - before + window, 0, len(x))
    n = c[hi] - c[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.asarray(np.where(n > 0, (v[hi] - v[lo]) / np.maximum(n, 1), np.nan), float)


def _runs(mask: BoolArray) -> list[tuple[int, int]]:
    """[start, stop) index ranges where mask is True."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=True))


def airborne_windows(flight: FlightLog) -> list[tuple[float, float]]:
    """(start_s, end_s) of each period armed and not landed, from the state signals."""
    ref = flight.accel_up_mps2 or flight.voltage_v
    if ref is None or not len(ref):
        return []
    t = ref.time_s
    air = np.ones(len(t), bool)
    if flight.armed is not None:
        air &= flight.armed.hold(t) > 0.5
    if flight.landed is not None:
        air &= flight.landed.hold(t) < 0.5
    return [(float(t[a]), float(t[b - 1])) for a, b in _runs(air)]


# -- time sanity ---------------------------------------------------------------------------------

#: a pause in the log longer than this splits it into stretches (logging stopped, a new flight)
TIME_JUMP_S = 60.0
#: the resampled timeline may hold at most this many bins per accelerometer sample (plus a
#: constant): a span the samples cannot fill is a corrupt or mistyped time, not a flight
BINS_PER_SAMPLE = 4
BINS_SLACK = 36_000


def plausible_timeline(acc: Signal, rate_hz: float, path: str) -> tuple[Signal, list[str]]:
    """The accelerometer samples whose times are plausible, and warnings for those dropped.

    One mistyped or bit-flipped time (``3005000`` among 0..300 s) would otherwise make the
    resampled timeline span weeks: gigabytes of empty bins. Samples with non-finite times, and
    stretches (separated by more than TIME_JUMP_S) too small to be flying (fewer than 5 samples
    or 0.1 % of the log), are dropped with a warning; if the remaining span still needs far more
    bins than there are samples, the log's times are refused. Memory stays bounded by the input.
    """
    t = acc.time_s
    warnings: list[str] = []
    keep = np.isfinite(t)
    if not keep.all():
        warnings.append(f"{int((~keep).sum())} accelerometer samples without a valid time dropped")
    t_ok = t[keep]
    if not len(t_ok):
        raise DataFormatError("no accelerometer sample has a valid time", file=path)
    order_ok = bool(np.all(np.diff(t_ok) >= 0))
    if not order_ok:
        raise DataFormatError(
            "accelerometer times go backwards; expected increasing timestamps", file=path
        )
    breaks = np.flatnonzero(np.diff(t_ok) > TIME_JUMP_S) + 1
    bounds = [0, *breaks.tolist(), len(t_ok)]
    minimum = max(5, len(t_ok) // 1000)
    idx_ok = np.flatnonzero(keep)
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        if b - a < minimum and len(bounds) > 2:
            keep[idx_ok[a:b]] = False
            warnings.append(
                f"{b - a} sample(s) at t = {t_ok[a]:.6g} s dropped: isolated by a time jump of "
                f"more than {TIME_JUMP_S:g} s from the rest of the log (a corrupt or mistyped time?)"
            )
    if not keep.any():
        raise DataFormatError("no accelerometer samples left after dropping time jumps", file=path)
    kept_t = t[keep]
    span_s = float(kept_t[-1] - kept_t[0])
    max_bins = BINS_PER_SAMPLE * len(kept_t) + BINS_SLACK
    if span_s * rate_hz > max_bins:
        raise DataFormatError(
            f"the log's times span {span_s:.6g} s for only {len(kept_t)} accelerometer samples; "
            "expected a flight's timestamps (a corrupt or mistyped time?)",
            file=path,
        )
    if keep.all():
        return acc, warnings
    return Signal(t[keep], acc.values[keep], acc.unit, acc.origin), warnings


# -- thrust command from motor outputs -----------------------------------------------------------


def motor_pct_in_map_scale(
    native_pct: FloatArray, log_scale: ThrottleScale, map_scale: ThrottleScale
) -> tuple[FloatArray, str]:
    """Motor outputs (percent of the log's scale) as percent of the map's throttle scale."""
    if log_scale.unit == map_scale.unit:
        native = log_scale.from_pct(native_pct)
        return map_scale.to_pct(native), f"native {log_scale.unit} values through the map's scale"
    return native_pct, (
        f"assumed {log_scale.name} {log_scale.lo:g}..{log_scale.hi:g} spans the map's "
        f"{map_scale.name} {map_scale.lo:g}..{map_scale.hi:g} range"
    )


def thrust_from_motors(
    map_pct: FloatArray, voltage_v: FloatArray, tmap: ThrustMap, rotors: int
) -> FloatArray:
    """Collective T_c (N): per-rotor map forward, summed over rotors. One column = all rotors."""
    per_rotor = tmap.thrust_n(map_pct, voltage_v[:, None], corrected=False)
    if map_pct.shape[1] == 1:
        return np.asarray(per_rotor[:, 0] * rotors, float)
    return np.asarray(per_rotor.sum(axis=1), float)


# -- extraction ----------------------------------------------------------------------------------


def _ground_level(height: FloatArray, stay: tuple[int, int]) -> float:
    """Median height over the last second (10 bins) of a stay on the ground... or its first
    second when it is the stay after a landing (callers pass the slice they mean)."""
    a, b = stay
    seg = height[a:b]
    return float(nanmedian(seg)) if np.isfinite(seg).any() else float("nan")


def _height_trusted(height: FloatArray, ground: BoolArray) -> str | None:
    """Why an altitude signal cannot be trusted near the ground (None when it can): while the
    vehicle stands on the ground its altitude must stay put (a hot barometer drifts by metres)."""
    if not np.isfinite(height).any():
        return "no altitude samples"
    for a, b in _runs(ground):
        seg = height[a:b]
        seg = seg[np.isfinite(seg)]
        if len(seg) >= 10:
            ranked = np.sort(seg)  # 5th and 95th percentiles (linear), without np.percentile's
            lo, hi = np.interp([0.05, 0.95], np.linspace(0.0, 1.0, len(ranked)), ranked)  # imports
            if hi - lo > GROUND_HEIGHT_SPREAD_M:
                return f"altitude moves {hi - lo:.1f} m while the vehicle stands on the ground"
    return None


def _long_runs(mask: BoolArray, min_len: int) -> BoolArray:
    """``mask`` with its True runs shorter than ``min_len`` bins cleared."""
    out = np.zeros(len(mask), bool)
    for a, b in _runs(mask):
        if b - a >= min_len:
            out[a:b] = True
    return out


def _dilate(mask: BoolArray, radius: int) -> BoolArray:
    """True within ``radius`` bins of a True bin."""
    if radius <= 0 or not mask.any():
        return mask
    c = np.concatenate([[0], np.cumsum(mask.astype(np.int64))])
    n = len(mask)
    idx = np.arange(n)
    lo = np.clip(idx - radius, 0, n)
    hi = np.clip(idx + radius + 1, 0, n)
    return np.asarray((c[hi] - c[lo]) > 0)


def _supported(
    cmd: FloatArray,
    a_up: FloatArray,
    est: FloatArray | None,
    stretches: list[tuple[int, int]],
    opts: DfOptions,
) -> BoolArray:
    """Bins where the vehicle rests on the ground anywhere in a stretch, by physics: in free
    flight the upward specific force follows the thrust (a command well below hover gives
    a_up well below g); a vehicle carried by the ground reads g whatever the command. Hover is
    the autopilot's estimate when it has one (same units as ``cmd``), else the stretch's
    median command. Only runs of at least ``ground_min_s`` count (a brief dip in the command
    is the rotor lag and the accelerometer smoothing, not a touchdown)."""
    n = len(cmd)
    sup = np.zeros(n, bool)
    at_g = np.abs(np.nan_to_num(a_up, nan=0.0) - G0) <= opts.accel_tol_mps2
    for a, b in stretches:
        c = cmd[a:b]
        if not np.isfinite(c).any():
            continue
        level = float("nan")
        if est is not None and np.isfinite(est[a:b]).any():
            level = float(nanmedian(est[a:b]))
        if not level > 0:
            level = float(nanmedian(c))
        if not level > 0:
            continue
        with np.errstate(invalid="ignore"):
            low = np.nan_to_num(c, nan=np.inf) < opts.ground_cmd_frac * level
        sup[a:b] = low & at_g[a:b]
    return _long_runs(sup, max(1, int(round(opts.ground_min_s * opts.rate_hz))))


def _height_rule(
    height: FloatArray,
    stays: list[tuple[int, int]],
    stretches: list[tuple[int, int]],
    centres: FloatArray,
    opts: DfOptions,
    apply: Any,
    warnings: list[str],
    origin: str,
) -> None:
    """Airborne by altitude, with references that survive drift: near takeoff the level the
    vehicle left, near landing the level it came back to (each only within
    ``height_window_s`` of its end, so a drifted reference never cuts the middle of a
    flight); in between, back at the ground level (both levels agree) for ``ground_min_s``
    counts as supported. Levels that disagree by more than ``level_disagree_m`` are reported
    and then only judge their own end."""
    n = len(height)
    ok = np.ones(n, bool)
    mid = np.ones(n, bool)
    win = max(1, int(round(opts.height_window_s * opts.rate_hz)))
    min_len = max(1, int(round(opts.ground_min_s * opts.rate_hz)))
    drift_noted = False
    for a, b in stretches:
        before = [st for st in stays if st[1] <= a]
        after = [st for st in stays if st[0] >= b]
        lvl0 = lvl1 = float("nan")
        if before:
            sa, sb = before[-1]
            lvl0 = _ground_level(height, (max(sa, sb - 10), sb))
        if after:
            sa, sb = after[0]
            lvl1 = _ground_level(height, (sa, min(sb, sa + 10)))
        h = height[a:b]
        if np.isfinite(lvl0):
            w = min(win, b - a)
            up = np.flatnonzero(h[:w] - lvl0 >= opts.min_height_m)
            ok[a : a + (int(up[0]) if len(up) else w)] = False
        if np.isfinite(lvl1):
            w = min(win, b - a)
            up = np.flatnonzero(h[b - a - w :] - lvl1 >= opts.min_height_m)
            ok[(b - w + int(up[-1]) + 1 if len(up) else b - w) : b] = False
        if np.isfinite(lvl0) and np.isfinite(lvl1) and abs(lvl1 - lvl0) > opts.level_disagree_m:
            if not drift_noted:
                warnings.append(
                    f"{origin}: landing level {lvl1 - lvl0:+.1f} m from the takeoff level at "
                    f"t = {centres[b - 1]:.0f} s (altitude drift): each level judges only "
                    f"{opts.height_window_s:g} s near its own end"
                )
                drift_noted = True
            continue
        levels = [x for x in (lvl0, lvl1) if np.isfinite(x)]
        if not levels:
            continue
        ref = min(levels)  # the lower level: a drift can then hide a touchdown (physics still
        # sees it), never turn a low hover into one
        with np.errstate(invalid="ignore"):
            down = np.nan_to_num(h, nan=np.inf) - ref < 0.5 * opts.min_height_m
        mid[a:b] &= ~_long_runs(down, min_len)
    apply("height", f"before reaching {opts.min_height_m:g} m above the takeoff level, or after "
          f"leaving {opts.min_height_m:g} m above the landing level ({origin})", ok)  # fmt: skip
    apply("ground-altitude", f"back at the ground level for ≥ {opts.ground_min_s:g} s between "
          f"takeoff and landing, no land flag needed ({origin})", mid)  # fmt: skip


def _in_air_evidence(
    flight: FlightLog,
    centres: FloatArray,
    rs: Any,
    opts: DfOptions,
    apply: Any,
    warnings: list[str],
    cmd_pct: FloatArray | None,
    cmd_any: FloatArray | None = None,
    a_up: FloatArray | None = None,
) -> None:
    """Drop spool-up on the ground and the takeoff ramp with the autopilot's own in-air evidence.

    PX4's ``landed`` and ArduPilot's NOT_LANDED flip before the vehicle leaves the ground (the
    IMU reads ≈ g there, so the hover filter alone keeps ground samples). So, in this order:
    the land detector must report no ground contact (PX4 ground_contact / maybe_landed) and the
    autopilot's hover-thrust estimator must be valid (PX4); each airborne stretch then starts
    only once the vehicle is ``min_height_m`` above the level it took off from (altitude
    signal, when it holds still on the ground) and the command has reached
    before), and ends symmetrically before landing. A margin of ``settle_s`` is trimmed
    afterwards by the caller, then the climb rate must stay within ``climb_max_mps``
    (``_climb_rule``)."""
    ex = flight.extras
    n = len(centres)
    gc = ex.get("ground_contact")
    if gc is not None and len(gc):
        apply("ground-contact", f"land detector reports ground contact ({gc.origin})",
              gc.hold(centres) < 0.5)  # fmt: skip
    hv = ex.get("hover_estimate_valid")
    if hv is not None and len(hv):
        apply("hover-estimate", f"autopilot's hover-thrust estimate not valid ({hv.origin})",
              hv.hold(centres) > 0.5)  # fmt: skip
    # airborne stretches by the state signals alone (data gaps must not start a new stretch)
    ground = np.zeros(n, bool)
    if flight.armed is not None:
        ground |= flight.armed.hold(centres) < 0.5
    if flight.landed is not None:
        ground |= flight.landed.hold(centres) > 0.5
    if gc is not None and len(gc):
        ground |= gc.hold(centres) > 0.5
    stays = _runs(ground)
    stretches = _runs(~ground)
    hs = ex.get("height_m")
    rg = ex.get("range_m")
    if rg is not None and len(rg):  # height above the ground itself: no drift, where valid
        r = rs(rg)
        air = ~ground
        if r is not None and air.any() and np.isfinite(r[air]).mean() >= RANGE_COVERAGE:
            hs = rg
        elif r is not None:
            warnings.append(
                f"{rg.origin} not used: valid for only {np.isfinite(r[air]).mean():.0%} of the "
                f"airborne time (needs {RANGE_COVERAGE:.0%}); altitude used instead"
            )
    height = rs(hs) if hs is not None and len(hs) else None
    if height is not None:
        why = _height_trusted(height, ground)
        if why is not None:
            warnings.append(f"{hs.origin if hs else 'altitude'} not used: {why}")
            height = None
    if height is not None and opts.min_height_m > 0:
        _height_rule(height, stays, stretches, centres, opts, apply, warnings,
                     hs.origin if hs else "altitude")  # fmt: skip
    if cmd_pct is not None and opts.liftoff_frac > 0:
        ok = np.ones(n, bool)
        hover = flight.hover_thrust_estimate or ex.get("hover_throttle")
        est = rs(hover) * 100.0 if hover is not None else None
        for a, b in stretches:
            c = cmd_pct[a:b]
            if not np.isfinite(c).any():
                continue
            level = (
                float(nanmedian(est[a:b]))
                if est is not None and np.isfinite(est[a:b]).any()
                else float(nanmedian(c[len(c) // 4 : max(len(c) * 3 // 4, 1)]))
            )
            with np.errstate(invalid="ignore"):
                up = np.flatnonzero(c >= opts.liftoff_frac * level)
            if not len(up):
                ok[a:b] = False
                continue
            ok[a : a + int(up[0])] = False
            ok[a + int(up[-1]) + 1 : b] = False
        apply("liftoff", f"command below {opts.liftoff_frac:.0%} of the hover command before "
              "liftoff or after touchdown (spool-up / spool-down on the ground)", ok)  # fmt: skip
    if cmd_any is not None and opts.ground_cmd_frac > 0 and a_up is not None:
        hover = flight.hover_thrust_estimate or ex.get("hover_throttle")
        est = rs(hover) * 100.0 if hover is not None and cmd_pct is not None else None
        apply(
            "ground-physics",
            f"supported on the ground: command below {opts.ground_cmd_frac:.0%} of hover while "
            f"a_up stays at g for ≥ {opts.ground_min_s:g} s (no land flag needed)",
            ~_supported(
                cmd_pct if cmd_pct is not None and est is not None else cmd_any,
                a_up,
                est,
                stretches,
                opts,
            ),  # fmt: skip
        )


def _climb_rule(
    flight: FlightLog, rs: Any, opts: DfOptions, apply: Any, warnings: list[str]
) -> None:
    """Drop climbs and descents (the rotor's inflow changes its thrust). Applied after the
    takeoff/landing margin: a brief climb mid-flight is not a takeoff, and trimming
    ``settle_s`` around each one cost more than the climb itself (old ArduCopter logs)."""
    cs = flight.extras.get("climb_mps")
    if cs is not None and len(cs) and opts.climb_max_mps > 0:
        climb = rs(cs)
        if np.nanmax(np.abs(climb)) > 50.0:
            warnings.append(f"{cs.origin} not used: climb rates above 50 m/s are not physical")
        else:
            apply("climb", f"|climb rate| > {opts.climb_max_mps:g} m/s ({cs.origin})",
                  np.abs(np.nan_to_num(climb, nan=0.0)) <= opts.climb_max_mps)  # fmt: skip


#: an accelerometer reading further than this from g·cos(tilt) at rest is calibrated (m/s²)
REST_CAL_TOL_MPS2 = 0.1
#: ... when it rests this steadily there (standard deviation of the bin means, m/s²)
REST_STEADY_MPS2 = 0.3
#: the rest judged within this span before takeoff (s), ending this long before it (spool-up)
REST_SPAN_S, REST_MARGIN_S = 10.0, 1.0


def _rest_calibration(
    a_up: FloatArray,
    a_raw: FloatArray | None,
    cmd: FloatArray,
    tilt_deg: FloatArray | None,
    opts: DfOptions,
    apply: Any,
    warnings: list[str],
) -> FloatArray:
    """Rule "accel-calibration": calibrate a_up on the ground-rest segment before takeoff.

    Standing still on the ground the accelerometer must read g·cos(tilt) upward. Old boards
    logged far from it (8.35 and 10.55 m/s² at rest on the PXF ArduCopter 3.3-dev fleet) and
    F_m = m·a_up would carry the error whole. Rest: within ``REST_SPAN_S`` before the first
    time the command reaches ``liftoff_frac`` × the flight's median command (ending
    ``REST_MARGIN_S`` before it), the command below ``ground_cmd_frac`` of that, at least
    ``ground_min_s`` of it, a_up steady there. A bias and a scale error cannot be told apart
    from one attitude, and near hover (where Df keeps samples, a_up ≈ g) they are the same
    correction: a_up is scaled. Without a rest before takeoff nothing is changed (said)."""
    rate = opts.rate_hz
    raw = a_raw if a_raw is not None else a_up
    fin = np.isfinite(cmd) & np.isfinite(raw)
    level = float(nanmedian(cmd[fin & (cmd > 0)])) if (fin & (cmd > 0)).any() else float("nan")
    name, why = "accel-calibration", "a_up calibrated at rest before takeoff (drops nothing)"
    if not level > 0:
        apply(name, why, np.ones(len(a_up), bool))
        return a_up
    with np.errstate(invalid="ignore"):
        up = np.flatnonzero(fin & (cmd >= opts.liftoff_frac * level))
    end = (int(up[0]) if len(up) else 0) - int(round(REST_MARGIN_S * rate))
    start = max(0, end - int(round(REST_SPAN_S * rate)))
    seg = np.zeros(len(a_up), bool)
    if end > start:
        with np.errstate(invalid="ignore"):
            seg[start:end] = fin[start:end] & (cmd[start:end] < opts.ground_cmd_frac * level)
    if seg.sum() < max(2, int(round(opts.ground_min_s * rate))):
        apply(name, "no rest on the ground before takeoff in the log: a_up not calibrated",
              np.ones(len(a_up), bool))  # fmt: skip
        return a_up
    vals = raw[seg]
    measured = float(nanmedian(vals))
    tilt = float(nanmedian(tilt_deg[seg])) if tilt_deg is not None else float("nan")
    expected = G0 * float(np.cos(np.radians(tilt))) if np.isfinite(tilt) else G0
    rest_s = float(seg.sum() / rate)
    if float(np.std(vals)) > REST_STEADY_MPS2 or not 0.7 * G0 < measured < 1.3 * G0:
        apply(name, f"the {rest_s:.1f} s before takeoff are not a steady rest at about g: a_up "
              "not calibrated", np.ones(len(a_up), bool))  # fmt: skip
        return a_up
    if abs(measured - expected) <= REST_CAL_TOL_MPS2:
        apply(name, f"a_up at rest before takeoff {measured:.2f} m/s² (expected {expected:.2f}, "
              f"{rest_s:.1f} s): within {REST_CAL_TOL_MPS2:g}, not changed",
              np.ones(len(a_up), bool))  # fmt: skip
        return a_up
    k = expected / measured
    text = (
        f"accelerometer calibrated at rest: a_up read {measured:.2f} m/s² over {rest_s:.1f} s on "
        f"the ground before takeoff, expected {expected:.2f} (g·cos tilt); a_up × {k:.4f} for the "
        "whole flight (a bias and a scale error are the same correction near hover)"
    )
    warnings.append(text)
    apply(name, text, np.ones(len(a_up), bool))
    return np.asarray(a_up * k, float)


def _outside(values: FloatArray, lo: float, hi: float, what: str, unit: str) -> list[str]:
    v = values[np.isfinite(values)]
    if not len(v):
        return []
    out = []
    below, above = v < lo, v > hi
    if below.any():
        out.append(
            f"{below.mean():.0%} of the samples have {what} below the map's validity box "
            f"{lo:g}..{hi:g} {unit}, by up to {lo - float(v.min()):.3g} {unit} (extrapolated)"
        )
    if above.any():
        out.append(
            f"{above.mean():.0%} of the samples have {what} above the map's validity box "
            f"{lo:g}..{hi:g} {unit}, by up to {float(v.max()) - hi:.3g} {unit} (extrapolated)"
        )
    return out


def map_extrapolation(
    tmap: ThrustMap, voltage_v: FloatArray, thrust_per_rotor_n: FloatArray, what: str
) -> list[str]:
    """Warnings for Df samples outside the stand map's validity box (voltage, thrust), with how
    far: there the map extrapolates and γ absorbs the map's error."""
    box = tmap.validity
    return _outside(
        np.asarray(voltage_v, float), box.voltage_v.lo, box.voltage_v.hi, "battery voltage", "V"
    ) + _outside(np.asarray(thrust_per_rotor_n, float), box.thrust_n.lo, box.thrust_n.hi, what, "N")


def _flight_id(flight: FlightLog) -> str:
    return f"{Path(flight.path).name}#{flight.index}"


def select_motors(flight: FlightLog, rotors: int | None) -> FlightLog:
    """The flight with exactly ``rotors`` motor-output columns when the user gave a count.

    The readers take the motors from the log's frame (FRAME_CLASS / SERVOn_FUNCTION,
    CA_ROTOR_COUNT, the blackbox motor fields); a count given by the user overrides that: the
    first ``rotors`` of the frame's motors, or of all the log's outputs when it needs more."""
    sig = flight.motor_outputs
    if (
        rotors is None
        or sig is None
        or sig.values.ndim != 2
        or flight.metadata.get("motor_outputs_collective")
    ):
        return flight
    have = sig.values.shape[1]
    if have == rotors:
        return flight
    if rotors < have:
        new = Signal(sig.time_s, sig.values[:, :rotors], sig.unit,
                     f"{sig.origin} (first {rotors} of {have}: --rotors {rotors})")  # fmt: skip
        note = f"--rotors {rotors}: only the first {rotors} of the {have} motor outputs summed"
    else:
        allo = flight.extras.get("outputs_all")
        if allo is None or allo.values.ndim != 2 or allo.values.shape[1] < rotors:
            raise ConfigError(
                f"--rotors {rotors}, but the log has only {have} motor outputs ({sig.origin})"
            )
        new = Signal(allo.time_s, allo.values[:, :rotors], allo.unit,
                     f"{allo.origin.split(',')[0]}..{rotors} (--rotors {rotors})")  # fmt: skip
        note = f"--rotors {rotors}: outputs 1..{rotors} summed, the log's frame has {have} motors"
    return replace(flight, motor_outputs=new, warnings=[*flight.warnings, note])


def _voltage_missing(flight: FlightLog) -> str | None:
    """Why the flight has no usable battery voltage (None when it has one). The reader already
    questions voltages that cannot be physical (0 V throughout) and leaves them out."""
    if flight.voltage_v is not None and len(flight.voltage_v):
        return None
    why = [w for w in flight.warnings if "voltage" in w or "Volt" in w]
    return "; ".join(why) if why else "not in the log"


def extract_flight(
    flight: FlightLog, opts: DfOptions, tmap: ThrustMap | None = None
) -> tuple[pd.DataFrame, dict[str, Any], FlightReport]:
    """One flight's Df table (pandas), its sidecar entry and its filter report."""
    import pandas as pd

    columns, meta, report = extract_flight_columns(flight, opts, tmap)
    return pd.DataFrame(columns), meta, report


def extract_flight_columns(
    flight: FlightLog, opts: DfOptions, tmap: ThrustMap | None = None
) -> tuple[Columns, dict[str, Any], FlightReport]:
    """As ``extract_flight``, the table as columns of numpy arrays (no pandas needed)."""
    flight = select_motors(flight, opts.rotors)
    fid = _flight_id(flight)
    if flight.accel_up_mps2 is None or not len(flight.accel_up_mps2):
        why = [w for w in flight.warnings if "acceler" in w or "IMU" in w]
        raise DataFormatError(
            "flight log has no upward acceleration: a Df needs it for F_m"
            + (f" ({'; '.join(why)})" if why else ""),
            file=flight.path,
        )
    voltage_missing = _voltage_missing(flight)
    voltage_unknown = (
        None
        if voltage_missing is None
        else f"battery voltage unknown ({voltage_missing}): the Df's voltage_v column is empty, "
        "so γ can only be fitted as a constant and the stand map's forward direction (which "
        "needs B) cannot give T_c from the motor outputs"
    )
    mass = opts.mass_kg if opts.mass_kg is not None else flight.metadata.get("mass_kg")
    if mass is None:
        raise ConfigError("give the vehicle mass (--mass-kg): the log does not record it")
    acc, time_warnings = plausible_timeline(flight.accel_up_mps2, opts.rate_hz, flight.path)
    # every reader's acceleration is questioned here, not only the CSV readers': in g it is
    # converted and said, one that cannot be a specific force is refused (issue 31 item 8),
    # after the ground-rest calibration below: only what that cannot explain (issue 34)
    acc, unit_notes = specific_force_unit(acc)
    time_warnings = [*time_warnings, *unit_notes]
    t0 = float(acc.time_s[0])
    nbins = max(1, int(np.ceil((float(acc.time_s[-1]) - t0) * opts.rate_hz)) + 1)
    dt = 1.0 / opts.rate_hz
    centres: FloatArray = np.asarray(t0 + (np.arange(nbins) + 0.5) * dt, dtype=np.float64)

    binned: dict[int, FloatArray] = {}  # each signal is binned once (callers do not mutate)

    def rs(sig: Signal | None) -> FloatArray | None:
        if sig is None:
            return None
        if id(sig) not in binned:
            binned[id(sig)] = _bin_mean(sig, t0, opts.rate_hz, nbins, opts.max_gap_s)
        return binned[id(sig)]

    a_up = rs(acc)
    volt = rs(flight.voltage_v) if voltage_unknown is None else np.full(nbins, np.nan)
    assert a_up is not None and volt is not None
    has_data = np.isfinite(a_up)  # a sample in the bin, or one within max_gap_s
    if opts.accel_smooth_s > 0:
        a_up = _smooth(a_up, int(round(opts.accel_smooth_s * opts.rate_hz)))
    tilt = rs(flight.extras.get("tilt_deg"))
    steps: list[FilterStep] = []
    duration = float(nbins * dt)
    keep = np.ones(nbins, bool)

    def apply(name: str, reason: str, ok: BoolArray) -> None:
        nonlocal keep
        before = keep.sum()
        keep = keep & ok
        steps.append(
            FilterStep(name, reason, float((before - keep.sum()) * dt), float(keep.sum() * dt))
        )

    warnings = [w for w in flight.warnings if voltage_unknown is None or w not in voltage_unknown]
    warnings += time_warnings
    if voltage_unknown is not None:
        warnings.append(voltage_unknown)
    span_s = float(acc.time_s[-1] - acc.time_s[0]) if len(acc) > 1 else 0.0
    acc_rate_hz = (len(acc) - 1) / span_s if span_s > 0 else 0.0
    if 0 < acc_rate_hz < MIN_ACCEL_RATE_HZ:
        warnings.append(
            f"upward acceleration logged at only {acc_rate_hz:.0f} Hz ({acc.origin}): vibration "
            "aliases into a_up, so F_m scatters; log the IMU faster for a tighter γ"
        )
    # Rule "log-pause": no message of any kind within max_gap_s is the log pausing, not a gap
    # in the IMU: ArduCopter 3.2-3.3 write only while armed (motors.pde: init_disarm_motors
    # logs DISARMED then DataFlash.EnableWrites(false); init_arm_motors start_logging()), PX4
    # and others stop a log with the vehicle disarmed. Named apart from an accelerometer gap.
    paused = ~has_data
    for other in (flight.thrust_cmd_n, flight.thrust_cmd_norm, flight.motor_outputs,
                  flight.voltage_v):  # fmt: skip
        binned_other = rs(other) if other is not None and len(other) else None
        if binned_other is not None:
            fin = np.isfinite(binned_other)
            paused &= ~(fin if fin.ndim == 1 else fin.any(axis=1))
    apply("log-pause", f"the log pauses (no message within {opts.max_gap_s:g} s): logging "
          "stopped, e.g. disarmed (ArduCopter 3.2-3.3 log only while armed)", ~paused)  # fmt: skip
    apply("data", f"no accelerometer sample within {opts.max_gap_s:g} s (IMU gap)", has_data)
    if flight.armed is not None:
        apply("armed", "disarmed", flight.armed.hold(centres) > 0.5)
    else:
        warnings.append("no armed state in the log: every sample taken as armed")
    if flight.landed is not None:
        airborne = flight.landed.hold(centres) < 0.5
        apply("airborne", "landed (log's land detector)", airborne)
    else:
        airborne = np.ones(nbins, bool)
        warnings.append("no landed state in the log: airborne time judged by the filters alone")
    cmd_for_steady = rs(flight.thrust_cmd_n) if flight.thrust_cmd_n is not None else None
    if cmd_for_steady is None:
        cmd_for_steady = rs(flight.thrust_cmd_norm)
    if cmd_for_steady is None and flight.motor_outputs is not None:
        m = rs(flight.motor_outputs)
        if m is not None and flight.motor_output_scale is not None:
            m = flight.motor_output_scale.to_pct(m)
        cmd_for_steady = None if m is None else (m.mean(axis=1) if m.ndim == 2 else m)
    cmd_pct = cmd_for_steady
    if cmd_pct is not None and flight.thrust_cmd_n is None and flight.thrust_cmd_norm is not None:
        cmd_pct = cmd_pct * 100.0
    if cmd_for_steady is not None:
        a_up = _rest_calibration(a_up, rs(acc), cmd_for_steady, tilt, opts, apply, warnings)
    calibrated = any(w.startswith("accelerometer calibrated at rest") for w in warnings)
    refuse_unphysical_specific_force(a_up, acc.origin, flight.path,
                                     calibrated="its calibration at rest" if calibrated else "")  # fmt: skip
    _in_air_evidence(
        flight, centres, rs, opts, apply, warnings,
        cmd_pct if flight.thrust_cmd_n is None else None, cmd_for_steady, a_up,
    )  # fmt: skip
    # takeoff / landing transients: trim settle_s from both ends of every airborne run
    settled = np.zeros(nbins, bool)
    trim = int(round(opts.settle_s * opts.rate_hz))
    for a, b in _runs(keep):
        if b - a > 2 * trim:
            settled[a + trim : b - trim] = True
    apply("settle", f"within {opts.settle_s:g} s of takeoff or landing", settled)
    _climb_rule(flight, rs, opts, apply, warnings)
    apply(
        "hover",
        f"|a_up − g| > {opts.accel_tol_mps2:g} m/s² (not near hover)",
        np.abs(np.nan_to_num(a_up, nan=np.inf) - G0) <= opts.accel_tol_mps2,
    )
    sat = np.zeros(nbins, bool)
    sat_what = []
    norm_cmd = rs(flight.thrust_cmd_norm)
    if norm_cmd is not None:
        sat |= np.nan_to_num(norm_cmd, nan=0.0) >= SATURATED_NORM
        sat_what.append(f"normalised command ≥ {SATURATED_NORM:g}")
    if flight.motor_outputs is not None and flight.motor_output_scale is not None:
        binned_motors = rs(flight.motor_outputs)
        assert binned_motors is not None
        mpct = flight.motor_output_scale.to_pct(binned_motors)
        if mpct.ndim == 2 and mpct.shape[1] > 1:
            sat |= np.nan_to_num(mpct, nan=0.0).max(axis=1) >= SATURATED_NORM * 100.0
            sat_what.append(f"a motor output ≥ {SATURATED_NORM:.0%} of its range")
    if sat_what:
        apply("saturation", " or ".join(sat_what) + " (thrust limited: not steady flight)", ~sat)
    if cmd_for_steady is not None and keep.any():
        level = float(nanmedian(cmd_for_steady[keep]))
        with np.errstate(invalid="ignore"):
            near = np.abs(cmd_for_steady - level) <= 0.5 * abs(level)
        apply(
            "level", "command below half or above 1.5× the flight's median (idle on ground?)", near
        )
    if cmd_for_steady is not None and opts.steady_tol > 0:
        window = int(round(opts.steady_window_s * opts.rate_hz))
        steady = _steady(cmd_for_steady, window, opts.steady_tol)
        apply(
            "steady",
            f"command off its {opts.steady_window_s:g} s running median by > {opts.steady_tol:.0%}",
            steady,
        )
        # the rotor answers a command step within its lag; the bins straddling the step hold a
        # partial command and a_up is a centred running mean: drop those around every change
        lag = opts.rotor_lag_s + 0.5 * opts.accel_smooth_s + 1.0 / opts.rate_hz
        apply(
            "transient",
            f"within {lag:.2g} s of a command change > {opts.steady_tol:.0%} (rotor lag "
            f"{opts.rotor_lag_s:g} s, a_up smoothing, one bin)",
            ~_dilate(~steady & np.isfinite(cmd_for_steady), int(np.ceil(lag * opts.rate_hz))),
        )
    if tilt is not None:
        apply(
            "tilt",
            f"tilt > {opts.tilt_max_deg:g}°",
            np.nan_to_num(tilt, nan=0.0) <= opts.tilt_max_deg,
        )

    sources: dict[str, Any] = {
        "time_s": f"bin centres at {opts.rate_hz:g} Hz, from the first accelerometer sample",
        "voltage_v": None if flight.voltage_v is None else flight.voltage_v.origin,
        "accel_up_mps2": acc.origin
        + f" (bin mean at {opts.rate_hz:g} Hz, centred {opts.accel_smooth_s:g} s running mean)",
        "force_n": f"mass_kg × accel_up_mps2, collective (mass {mass:g} kg)",
    }
    cols: dict[str, FloatArray] = {"voltage_v": volt, "accel_up_mps2": a_up, "force_n": mass * a_up}
    # thrust command
    motors = rs(flight.motor_outputs)
    rotors = opts.rotors
    collective_motor = bool(flight.metadata.get("motor_outputs_collective"))
    if motors is not None and motors.ndim == 2 and rotors is None and not collective_motor:
        rotors = motors.shape[1]
    if motors is not None and flight.motor_output_scale is not None:
        pct = flight.motor_output_scale.to_pct(motors)
        for i in range(pct.shape[1]):
            cols[f"motor{i}_pct"] = pct[:, i]
        sc = flight.motor_output_scale
        sources["motor_pct"] = (
            f"{flight.motor_outputs.origin if flight.motor_outputs else ''} as % of "
            f"{sc.name} {sc.lo:g}..{sc.hi:g} {sc.unit}"
        )
        sources["motor_output_scale"] = sc.to_dict()
        sources["motor_output_scale_source"] = flight.metadata.get(
            "motor_output_scale_source", "not stated by the reader"
        )
        if "motor_channels" in flight.metadata:
            sources["motor_channels"] = flight.metadata["motor_channels"]
    norm = rs(flight.thrust_cmd_norm)
    if norm is not None:
        cols["thrust_cmd_norm"] = norm
        sources["thrust_cmd_norm"] = flight.thrust_cmd_norm.origin if flight.thrust_cmd_norm else ""
    src = opts.thrust_source
    t_cmd: FloatArray | None = None
    if flight.thrust_cmd_n is not None and src in ("auto", "log"):
        t_cmd = rs(flight.thrust_cmd_n)
        sources["thrust_cmd_n"] = flight.thrust_cmd_n.origin + " (collective, from the log)"
    elif src == "log":
        raise DataFormatError("the log has no thrust command in newtons", file=flight.path)
    needs_b = tmap is not None and (
        (src in ("auto", "motors") and motors is not None) or (src == "norm" and norm is not None)
    )
    if t_cmd is None and needs_b and voltage_unknown is not None:
        raise DataFormatError(
            "T_c must come from the motor outputs through the stand map, whose forward direction "
            f"needs the battery voltage, and the log has none ({voltage_missing}); extract "
            "without --map",
            file=flight.path,
        )
    if t_cmd is None and tmap is not None and src in ("auto", "motors") and motors is not None:
        assert flight.motor_output_scale is not None
        if rotors is None:
            raise ConfigError("give the rotor count (--rotors): the log has one throttle column")
        mp, how = motor_pct_in_map_scale(
            flight.motor_output_scale.to_pct(motors),
            flight.motor_output_scale,
            tmap.throttle_scale,
        )
        t_cmd = thrust_from_motors(mp, volt, tmap, rotors)
        cols["throttle_pct"] = mp.mean(axis=1)
        sources["throttle_pct"] = f"mean motor output, % of the map's scale ({how})"
        sources["thrust_cmd_n"] = (
            f"motor outputs through the stand map's forward direction, per rotor, summed over "
            f"{rotors} rotors ({how})"
        )
    if t_cmd is None and tmap is not None and src in ("auto", "norm") and norm is not None:
        if rotors is None:
            raise ConfigError("give the rotor count (--rotors) to turn the command into newtons")
        t_cmd = rotors * tmap.thrust_n(norm * 100.0, volt, corrected=False)
        cols["throttle_pct"] = norm * 100.0
        sources["thrust_cmd_n"] = (
            f"normalised collective command × 100 % of the map's scale through its forward "
            f"direction, × {rotors} rotors (assumes every motor gets the collective command)"
        )
    if t_cmd is not None:
        cols["thrust_cmd_n"] = t_cmd
    elif norm is None and motors is None:
        raise DataFormatError(
            "flight log has no thrust command (newtons, normalised or motor outputs)",
            file=flight.path,
        )
    else:
        warnings.append("no map given: T_c in newtons not computed (thrust_cmd_norm only)")
    if "throttle_pct" not in cols and motors is not None and flight.motor_output_scale is not None:
        cols["throttle_pct"] = flight.motor_output_scale.to_pct(motors).mean(axis=1)
        sources["throttle_pct"] = "mean motor output, % of the log's own scale"
    hover = flight.hover_thrust_estimate or flight.extras.get("hover_throttle")
    if hover is not None:
        cols["hover_thrust_est"] = _bin_mean(hover, t0, opts.rate_hz, nbins, opts.max_gap_s)
        sources["hover_thrust_est"] = hover.origin
    valid = np.isfinite(a_up) & (a_up > 0)
    if voltage_unknown is None:
        valid &= np.isfinite(volt) & (volt > 0)
    cmd = cols.get("thrust_cmd_n", cols.get("thrust_cmd_norm", cols.get("throttle_pct")))
    if cmd is not None:
        valid &= np.isfinite(cmd) & (cmd > 0)
    apply("values", "missing or non-positive voltage, acceleration or command", valid)
    table: Columns = {"flight": np.full(int(keep.sum()), fid, dtype=object),
                      "time_s": centres[keep]}  # fmt: skip
    for k, v in cols.items():
        table[k] = np.asarray(v, float)[keep]
    if tmap is not None and int(keep.sum()) and rotors:
        warnings.extend(
            map_extrapolation(
                tmap,
                table["voltage_v"],
                table["force_n"] / rotors,
                "per-rotor thrust (F_m / rotors)",
            )
        )
    if int(keep.sum()) < MIN_DF_SAMPLES:
        worst = sorted((st for st in steps if st.dropped_s > 0), key=lambda st: -st.dropped_s)
        warnings.append(
            f"only {int(keep.sum())} samples of steady flight (fewer than {MIN_DF_SAMPLES}): too "
            "short for a γ fit; most time dropped by "
            + ", ".join(f"{st.name} {st.dropped_s:.1f} s ({st.reason})" for st in worst[:3])
        )
    report = FlightReport(
        flight=fid,
        path=flight.path,
        format=flight.format,
        duration_s=duration,
        kept_s=float(keep.sum() * dt),
        samples=int(keep.sum()),
        steps=steps,
        warnings=warnings,
        voltage_unknown=voltage_unknown,
    )
    meta: dict[str, Any] = {"mass_kg": mass, "rotors": rotors, "sources": sources}
    if voltage_unknown is not None:
        meta["voltage_source"] = None
        meta["voltage_unknown"] = voltage_missing
    return table, meta, report


def extract(flights: list[FlightLog], opts: DfOptions, tmap: ThrustMap | None = None) -> Df:
    """Df from every flight; each keeps its own id in the ``flight`` column."""
    tables: list[Columns] = []
    reports = []
    sources: dict[str, Any] = {}
    per_flight: dict[str, Any] = {}
    for fl in flights:
        table, meta, report = extract_flight_columns(fl, opts, tmap)
        tables.append(table)
        reports.append(report)
        per_flight[report.flight] = meta
        for k, v in meta["sources"].items():
            sources.setdefault(k, v)
    side = {
        "format": DF_FORMAT,
        "version": 1,
        "thrust_meaning": "collective (all rotors), N; the stand map is per rotor",
        "columns": sources,
        "flights": per_flight,
        "options": asdict(opts),
        "map": None if tmap is None else {"model": tmap.model, "sha256": tmap.file_sha256},
        "reports": [r.to_dict() for r in reports],
    }
    return Df(None, side, reports, columns=_concat(tables))


def _concat(tables: list[Columns]) -> Columns:
    """Rows of every flight, columns in order of first appearance, NaN where a flight lacks one
    (as pandas.concat)."""
    names: list[str] = []
    for t in tables:
        names.extend(k for k in t if k not in names)
    out: Columns = {}
    for k in names:
        parts = []
        for t in tables:
            n = len(t["time_s"])
            if k in t:
                parts.append(t[k])
            else:
                parts.append(
                    np.full(
                        n, np.nan if k != "flight" else "", dtype=object if k == "flight" else float
                    )
                )
        out[k] = np.concatenate(parts) if parts else np.zeros(0)
    return out


def _csv_text(columns: Columns) -> str:
    """The Df CSV as pandas writes it (``float_format='%.6g'``, NaN as an empty field)."""
    buf = io.StringIO()
    names = list(columns)
    if not names:
        return "\n"
    csv.writer(buf, lineterminator="\n").writerow(names)
    cells = []
    for k in names:
        v = columns[k]
        if v.dtype == object or v.dtype.kind in "US":
            cells.append([_csv_cell(str(x)) for x in v])
        else:
            cells.append(["" if x != x else f"{x:.6g}" for x in np.asarray(v, float).tolist()])
    buf.writelines(",".join(row) + "\n" for row in zip(*cells, strict=True))
    return buf.getvalue()


def _csv_cell(text: str) -> str:
    if any(c in text for c in ',"\n\r'):
        return '"' + text.replace('"', '""') + '"'
    return text


def sidecar_path(csv_path: str | Path) -> Path:
    return Path(csv_path).with_suffix(".json")


def write_df(df: Df, path: str | Path) -> Path:
    """Write the Df CSV and its sidecar, each atomically; the sidecar is never the CSV itself."""
    p = Path(path)
    side = sidecar_path(p)
    if side.resolve() == p.resolve():
        raise ConfigError(
            f"the Df output needs a name its sidecar ({side.name}) does not share; use .csv",
            file=str(p),
        )
    if df._table is not None:  # a table given (or touched) as pandas: written by pandas
        text = df._table.to_csv(index=False, float_format="%.6g")
    else:
        text = _csv_text(df._columns or {})
    atomic_write_text(p, text)
    atomic_write_text(side, json.dumps(df.sources, indent=2, default=str) + "\n")
    return side


def _positive_int(value: Any) -> bool:
    """A count: an integer ≥ 1 (a JSON 4.0 is accepted, 4.5, "four", true are not)."""
    if isinstance(value, bool):
        return False
    if isinstance(value, int):
        return value >= 1
    return isinstance(value, float) and value.is_integer() and value >= 1


def _check_sidecar(side: dict[str, Any], path: str) -> None:
    """Refuse sidecar fields the γ fit relies on when they cannot be what they name."""
    flights = side.get("flights", {})
    if not isinstance(flights, dict):
        raise DataFormatError(
            "Df sidecar: 'flights' must be an object", file=path, column="flights"
        )
    for fid, meta in flights.items():
        if not isinstance(meta, dict):
            raise DataFormatError(
                "Df sidecar: expected an object per flight", file=path, column=f"flights.{fid}"
            )
        for key in ("rotors", "mass_kg"):
            value = meta.get(key)
            if value is None:
                continue
            if key == "rotors" and not _positive_int(value):
                raise DataFormatError(
                    f"Df sidecar: rotor count {value!r} is not a whole number ≥ 1",
                    file=path,
                    column=f"flights.{fid}.rotors",
                )
            if key == "mass_kg" and (
                isinstance(value, bool) or not isinstance(value, int | float) or not 0 < value < 1e5
            ):
                raise DataFormatError(
                    f"Df sidecar: mass {value!r} is not a positive number of kg",
                    file=path,
                    column=f"flights.{fid}.mass_kg",
                )
    opts = side.get("options")
    if (
        isinstance(opts, dict)
        and opts.get("rotors") is not None
        and not _positive_int(opts["rotors"])
    ):
        raise DataFormatError(
            f"Df sidecar: rotor count {opts['rotors']!r} is not a whole number ≥ 1",
            file=path,
            column="options.rotors",
        )


def read_df(path: str | Path) -> tuple[pd.DataFrame, dict[str, Any]]:
    """A Df CSV and its sidecar (empty dict when the sidecar is absent)."""
    import pandas as pd

    p = Path(path)
    try:
        table = pd.read_csv(p, dtype=str, keep_default_na=False, engine="c")
    except FileNotFoundError:
        raise DataFormatError("Df file not found", file=str(p)) from None
    except OSError as exc:
        raise DataFormatError(f"cannot read Df file: {exc.strerror}", file=str(p)) from None
    except (pd.errors.ParserError, pd.errors.EmptyDataError, ValueError) as exc:
        reason = " ".join(str(exc).split())[:200]
        raise DataFormatError(f"not a Df CSV: {reason}", file=str(p)) from None
    for need in ("voltage_v", "force_n"):
        if need not in table.columns:
            raise DataFormatError(
                "not a Df CSV (expected columns time_s, voltage_v, accel_up_mps2, force_n, "
                "thrust_cmd_n and/or thrust_cmd_norm)",
                file=str(p),
                column=need,
            )
    for col in table.columns:
        if col == "flight":
            continue
        text = table[col].str.strip()
        num = pd.to_numeric(text.where(text != "", "nan"), errors="coerce")
        bad = num.isna().to_numpy() & ~text.str.lower().isin(["", "nan"]).to_numpy()
        with np.errstate(invalid="ignore"):
            bad |= np.isinf(num.to_numpy(dtype=float))
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            cell = str(table[col].iloc[row])
            shown = cell if len(cell) <= 40 else f"{cell[:40]}... ({len(cell)} characters)"
            raise DataFormatError(
                f"expected a finite number, got {shown!r}", file=str(p), line=row + 2, column=col
            )
        table[col] = num.astype(float)
    side: dict[str, Any] = {}
    sp = sidecar_path(p)
    if sp.exists() and sp.resolve() != p.resolve():
        loaded = load_json(sp, what="Df sidecar")
        if not isinstance(loaded, dict):
            raise DataFormatError("Df sidecar: expected a JSON object", file=str(sp))
        side = loaded
        _check_sidecar(side, str(sp))
    if "flight" not in table.columns:
        table.insert(0, "flight", p.name)
    return table, side


def hover_throttle(table: pd.DataFrame) -> float:
    """The normalised collective command needed to hover: median of norm · g / a_up."""
    if "thrust_cmd_norm" not in table.columns or not len(table):
        raise DataFormatError("Df has no normalised thrust command to estimate hover throttle")
    ratio = table["thrust_cmd_norm"].to_numpy(float) * G0 / table["accel_up_mps2"].to_numpy(float)
    return float(nanmedian(ratio))
