"""Steady-state extraction over one file: staircases (paired or read leg by leg), plateaus,
then ramps (up and down ramps paired, quasi-static samples kept), with its report."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from thrustmap.core.errors import FitError
from thrustmap.fitting.dataset import SAMPLE_AND_HOLD, Dataset, FloatArray
from thrustmap.fitting.selection.creep import creep_correction
from thrustmap.fitting.selection.options import (
    ROLE_PLATEAU,
    ROLE_RAMP,
    ROLE_SETTLING,
    ROLE_STAIR_PAIR,
    Selection,
)
from thrustmap.fitting.selection.plateaus import (
    plateau_levels,
    row_period,
    sensor_updates,
    settle_index,
    still_trends,
)
from thrustmap.fitting.selection.stairs import (
    Paired,
    Stair,
    legs_disagree,
    pair_legs,
    settled_updates,
    stair_legs,
)


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


def steady_state(
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
    fresh, held = sensor_updates(ds.thrust_n, th, tol, known)
    t_out: list[float] = []
    b_out: list[float] = []
    th_out: list[float] = []
    kinds: list[str] = []
    point_at_rest: list[bool] = []  # per point: most of its samples had the rotor stopped
    n_plateau_samples = n_settle_dropped = n_ramp_kept = 0
    n_runner_settled = n_trending = n_unsettled = 0
    in_plateau = np.zeros(len(ds), dtype=bool)
    roles = np.zeros(len(ds), dtype=np.int8)
    levels = plateau_levels(ds, tol)
    # per-level sums from cumulative sums: one pass, however many levels a file has
    period = row_period(ds)
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
        Stair(
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
    all_legs = stair_legs(sub, tol, sel.min_stair_legs)
    sub_at_rest = np.array([bool(stopped[st.a : st.b].mean() > 0.5) for st in sub], dtype=bool)
    legpairs = Paired()
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
                settled[i] = settled_updates(ds.thrust_n, fresh, sub[i], sel.settle_sigmas)
        held_for = [len(settled[i]) for i in up_leg + down_leg if i != l1[-1]]
        if held_for and float(np.median(held_for)) >= sel.leg_plateau_updates:
            legged.append((up_leg, down_leg, l1[-1]))
            continue
        one = pair_legs(sub, up_leg, down_leg, l1[-1], rest_n, sel, sub_at_rest)
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
        found = creep_correction(ds.thrust_n, same_command, ds.voltage_v)
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
        dc, dt_rel = legs_disagree(
            np.asarray(ds.throttle_scale.to_pct(np.asarray(th_out[first:])))[moving],
            np.asarray(t_out[first:])[moving],
            np.asarray(b_out[first:])[moving],
            mine[moving],
        )
        d_cmd_all += dc
        d_thr_all += dt_rel
        d_thr_raw += legs_disagree(
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
            k = settle_index(ds.thrust_n[upd], sel.settle_sigmas)
            start = int(upd[k]) if k < len(upd) else b
        kept = upd[upd >= start]
        if len(kept) < 2:
            n_unsettled += 1
            continue
        if still_trends(ds.thrust_n[kept], sel):
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
