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
trends (the means of its two halves differ beyond the noise) is dropped. Stairs too short to
settle (fewer than ``min_plateau_samples`` sensor updates) are paired: on a staircase up and
back down, the level on the up-leg and the same command on the adjacent down-leg lag in
opposite directions, so their mean cancels the lag (no time column needed); a pair where one leg
reads next to nothing (under ``stall_fraction`` of the other above the rest reading: a rotor that
had not started on the way up) is dropped. Points where the rotor is stopped (command at the bottom of the scale, or rpm zero where
the log has rpm) read the load cell's offset: tare information, reported. A positive command
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
    # Zero-command points (rotor at rest: thrust is the load cell's offset) are reported as tare
    # information; True also drops them from the map. Off by default: the default 'motor' model
    # pins its offset on the zero-command point (xNova by-file 0.51 % with it, 1.44 % without).
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
            "drop_tare_points": self.drop_tare_points,
        }


@dataclass(frozen=True)
class Points:
    """Fit points from one file: plateau means, quasi-static ramp samples, or raw samples."""

    source: str
    thrust_n: FloatArray
    voltage_v: FloatArray
    throttle_pct: FloatArray
    kind: npt.NDArray[np.str_]  # "plateau", "ramp-pair", "ramp", "step-summary" or "sample"
    report: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.thrust_n)


def _in_range(x: FloatArray, rng: tuple[float, float] | None) -> npt.NDArray[np.bool_]:
    if rng is None:
        return np.ones(len(x), dtype=bool)
    return np.asarray((x > rng[0]) & (x < rng[1]), dtype=bool)


def select(ds: Dataset, sel: Selection) -> Points:
    """Apply steady-state extraction (unless ``all_samples``) and the range filters."""
    report: dict[str, Any] = {"file": ds.name, "samples": len(ds)}
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
            t, b, th, kind, stopped, info = _steady_state(ds, sel, _rotor_stopped(ds, sel))
            report.update(info)
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
    return Points(
        source=ds.name,
        thrust_n=t[keep],
        voltage_v=b[keep],
        throttle_pct=ds.throttle_scale.to_pct(th[keep]),
        kind=kind[keep],
        report=report,
    )


def _rotor_stopped(ds: Dataset, sel: Selection) -> npt.NDArray[np.bool_]:
    """Samples with the rotor stopped: a command at the bottom of the scale (within the plateau
    tolerance), or, where the log has rpm that rises above 1000, rpm under 1 % of its maximum.
    Their thrust is the load cell's offset, not a point of the map."""
    stopped = ds.throttle_pct <= sel.plateau_tolerance_pct
    if ds.rpm is not None and np.isfinite(ds.rpm).any():
        top = float(np.nanmax(ds.rpm))
        if top > 1000.0:
            stopped = stopped | (np.nan_to_num(ds.rpm, nan=np.inf) < 0.01 * top)
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


def _stair_pairs(
    stairs: list[tuple[float, float, float, npt.NDArray[np.int64]]], tol: float, min_legs: int
) -> list[tuple[int, int]]:
    """Index pairs (up-leg stair, down-leg stair) at equal command, from adjacent legs of
    consecutive stairs (``stairs``: command, thrust, voltage, samples — in file order)."""
    legs: list[tuple[int, list[int]]] = []  # (direction, stair indices)
    for i in range(1, len(stairs)):
        step = stairs[i][0] - stairs[i - 1][0]
        d = 0 if abs(step) <= tol else (1 if step > 0 else -1)
        contiguous = stairs[i][3][0] - stairs[i - 1][3][-1] <= 1
        if d and contiguous and legs and legs[-1][0] == d and legs[-1][1][-1] == i - 1:
            legs[-1][1].append(i)
        elif d and contiguous:
            legs.append((d, [i - 1, i]))
    legs = [(d, leg) for d, leg in legs if len(leg) >= min_legs]
    pairs: list[tuple[int, int]] = []
    for (d1, l1), (d2, l2) in zip(legs, legs[1:], strict=False):
        if d1 == d2 or l1[-1] != l2[0] and l2[0] - l1[-1] > 1:
            continue
        up, down = (l1, l2) if d1 > 0 else (l2, l1)
        for u in up:
            match = [w for w in down if abs(stairs[w][0] - stairs[u][0]) <= tol and w != u]
            if match:
                pairs.append((u, match[0]))
    return pairs


def _steady_state(
    ds: Dataset, sel: Selection, stopped: npt.NDArray[np.bool_]
) -> tuple[
    FloatArray,
    FloatArray,
    FloatArray,
    np.ndarray[Any, Any],
    npt.NDArray[np.bool_],
    dict[str, Any],
]:
    """Points, their kinds, whether each was taken with the rotor mostly stopped, and a report."""
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
    stairs: list[tuple[float, float, float, npt.NDArray[np.int64]]] = []
    for a, b, settled_from in _levels(ds, tol):
        upd = a + np.flatnonzero(fresh[a:b])  # samples with a new thrust reading
        if len(upd) < sel.min_plateau_samples:
            if b - a >= 2 and len(upd):
                # a stair too short for the sensor to settle: a candidate for leg pairing
                stairs.append(
                    (
                        float(np.mean(th[a:b])),
                        float(np.mean(ds.thrust_n[upd])),
                        float(np.mean(ds.voltage_v[a:b])),
                        np.arange(a, b),
                    )
                )
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
        t_out.append(float(np.mean(ds.thrust_n[kept])))
        b_out.append(float(np.mean(ds.voltage_v[start:b])))
        th_out.append(float(np.mean(th[start:b])))
        kinds.append("plateau")
        point_at_rest.append(bool(stopped[start:b].mean() > 0.5))
    # Staircases too fast for the sensor: pair each up-leg stair with the down-leg stair at the
    # same command; the rotor (and a held load cell) lags low going up and high coming down.
    n_stair_pairs = n_stalled = 0
    at_rest = [
        t for c, t, _, _ in stairs if ds.throttle_scale.to_pct(c) <= sel.plateau_tolerance_pct
    ]
    rest_n = float(np.median(at_rest)) if at_rest else 0.0
    for u, w in _stair_pairs(stairs, tol, sel.min_stair_legs):
        cu, tu, vu, su = stairs[u]
        cw, tw, vw, sw = stairs[w]
        mean_t = (tu + tw) / 2.0
        lo, hi = sorted((tu - rest_n, tw - rest_n))
        if hi <= 0 or lo <= sel.stall_fraction * hi:
            n_stalled += 1
            continue
        t_out.append(mean_t)
        b_out.append((vu + vw) / 2.0)
        th_out.append((cu + cw) / 2.0)
        kinds.append("stair-pair")
        point_at_rest.append(bool(stopped[np.concatenate([su, sw])].mean() > 0.5))
        in_plateau[su] = True
        in_plateau[sw] = True
        n_stair_pairs += 1
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
        quasi = on_ramp & ~paired & (slew_pct_s * sel.ramp_lag_s <= sel.lag_budget_pct)
        idx = np.flatnonzero(quasi)
        n_ramp_kept = len(idx) + int(paired.sum())
        t_out.extend(ds.thrust_n[idx].tolist())
        b_out.extend(ds.voltage_v[idx].tolist())
        th_out.extend(th[idx].tolist())
        kinds.extend(["ramp"] * len(idx))
        point_at_rest.extend(stopped[idx].tolist())
    if not t_out:
        raise FitError(
            "no steady-state points found (no throttle plateau of "
            f"{sel.min_plateau_samples}+ samples, no slow ramp); use --all-samples to fit raw samples",
            file=ds.path,
        )
    info = {
        "plateaus": kinds.count("plateau"),
        "plateaus_settled_by_recorder": n_runner_settled,
        "plateau_samples": n_plateau_samples,
        "settling_samples_dropped": n_settle_dropped,
        "ramp_samples_kept": n_ramp_kept,
        "ramp_pair_points": n_paired,
        "transient_samples_dropped": len(ds) - n_plateau_samples - n_ramp_kept,
        **held,
    }
    rules = {
        "plateaus_dropped_still_trending": n_trending,
        "plateaus_dropped_unsettled": n_unsettled,
        "stair_pairs": n_stair_pairs,
        "stair_pairs_dropped_stalled": n_stalled,
    }
    info.update({k: v for k, v in rules.items() if v})
    if at_rest:  # zero-command stairs too short to be points: still the rest reading
        info["tare_points"] = len(at_rest)
        info["tare_offset_n"] = round(rest_n, 6)
    return (
        np.asarray(t_out),
        np.asarray(b_out),
        np.asarray(th_out),
        np.asarray(kinds),
        np.asarray(point_at_rest, dtype=bool),
        info,
    )
