"""When the vehicle flies free: the state signals, the altitude and the physics that tell
ground from air, the climb rule, and the accelerometer's calibration at rest before
takeoff. Each rule reports what it drops through the ``apply`` callback of the extraction."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from thrustmap.fitting.df.options import (
    G0,
    GROUND_HEIGHT_SPREAD_M,
    RANGE_COVERAGE,
    BoolArray,
)
from thrustmap.fitting.df.resample import long_runs, mask_runs
from thrustmap.fitting.df_options import DfOptions
from thrustmap.flightlogs.series import FlightLog, FloatArray, nanmedian

if TYPE_CHECKING:
    from thrustmap.fitting.df.flight_run import FlightRun


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
    return [(float(t[a]), float(t[b - 1])) for a, b in mask_runs(air)]


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
    for a, b in mask_runs(ground):
        seg = height[a:b]
        seg = seg[np.isfinite(seg)]
        if len(seg) >= 10:
            ranked = np.sort(seg)  # 5th and 95th percentiles (linear), without np.percentile's
            lo, hi = np.interp([0.05, 0.95], np.linspace(0.0, 1.0, len(ranked)), ranked)  # imports
            if hi - lo > GROUND_HEIGHT_SPREAD_M:
                return f"altitude moves {hi - lo:.1f} m while the vehicle stands on the ground"
    return None


def _flying_level(cmd: FloatArray) -> float:
    """The median command of the bins that can fly: a command of zero holds every motor at
    its idle or armed spin (ArduCopter cuts the output to ``spin_when_armed`` at
    ``servo_out == 0``), which cannot carry a vehicle, so idle bins do not set the hover
    level (NaN when no bin commands thrust). An armed wait at idle between logging pauses
    otherwise made a stretch's level 0, and every bin passed ``c >= 0.9 × 0``."""
    with np.errstate(invalid="ignore"):
        up = cmd[np.isfinite(cmd) & (cmd > 0)]
    return float(nanmedian(up)) if len(up) else float("nan")


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
            level = _flying_level(c)
        if not level > 0:
            continue
        with np.errstate(invalid="ignore"):
            low = np.nan_to_num(c, nan=np.inf) < opts.ground_cmd_frac * level
        sup[a:b] = low & at_g[a:b]
    return long_runs(sup, max(1, int(round(opts.ground_min_s * opts.rate_hz))))


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
        mid[a:b] &= ~long_runs(down, min_len)
    apply("height", f"before reaching {opts.min_height_m:g} m above the takeoff level, or after "
          f"leaving {opts.min_height_m:g} m above the landing level ({origin})", ok)  # fmt: skip
    apply("ground-altitude", f"back at the ground level for ≥ {opts.ground_min_s:g} s between "
          f"takeoff and landing, no land flag needed ({origin})", mid)  # fmt: skip


def _hover_pct(run: FlightRun) -> FloatArray | None:
    """The autopilot's hover-thrust estimate on the bins, in % (None: the log has none)."""
    hover = run.flight.hover_thrust_estimate or run.flight.extras.get("hover_throttle")
    binned = run.rs(hover)
    return None if binned is None else binned * 100.0


def in_air_evidence(
    run: FlightRun,
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
    (``climb_rule``)."""
    flight, centres, rs, opts = run.flight, run.centres, run.rs, run.opts
    apply, warnings = run.apply, run.warnings
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
    stays = mask_runs(ground)
    stretches = mask_runs(~ground)
    hs = ex.get("height_m")
    rg = ex.get("range_m")
    if rg is not None and len(rg):  # height above the ground itself: no drift, where valid
        r = rs(rg)
        air = ~ground
        if r is not None and air.any() and np.isfinite(r[air]).mean() >= RANGE_COVERAGE:
            hs = rg
        elif r is not None and air.any():  # (no airborne time: nothing to judge it on)
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
        est = _hover_pct(run)
        for a, b in stretches:
            c = cmd_pct[a:b]
            if not np.isfinite(c).any():
                continue
            level = (
                float(nanmedian(est[a:b]))
                if est is not None and np.isfinite(est[a:b]).any()
                else _flying_level(c[len(c) // 4 : max(len(c) * 3 // 4, 1)])
            )
            if not level > 0:  # the middle of the stretch idles: the level of what flies
                level = _flying_level(c)
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
        est = _hover_pct(run) if cmd_pct is not None else None
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


def climb_rule(
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


def rest_calibration(
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
