"""Steady-state extraction over one file, as an ordered list of rules (``RULES``): quasi-static
staircases (up and down legs paired), staircases read leg by leg (a plateau per stair, the
legs' disagreement and any load-cell creep measured), the remaining plateaus, then ramps (up and
down ramps paired, quasi-static samples kept). Each rule adds points to one ``_Run`` and counts
what it kept and dropped in its ``SteadyReport``; ``steady_state`` runs them and returns a
``SteadyState``."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
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


@dataclass
class SteadyReport:
    """What the rules kept and dropped (the selection report's counts)."""

    plateau_samples: int = 0
    settling_samples_dropped: int = 0
    ramp_samples_kept: int = 0
    ramp_pair_points: int = 0
    stair_pair_samples: int = 0
    plateaus_settled_by_recorder: int = 0
    plateaus_dropped_still_trending: int = 0
    plateaus_dropped_unsettled: int = 0
    stair_pairs: int = 0
    stair_pairs_dropped_stalled: int = 0
    stair_pairs_dropped_voltage_apart: int = 0
    turning_stairs_dropped_unsettled: int = 0
    quasi_static_legs_unpaired: int = 0
    #: quasi-static staircases: dwell, sensor updates per stair, legs, lag
    staircase: dict[str, Any] = field(default_factory=dict)
    #: staircases read leg by leg: legs, their disagreement, any load-cell creep
    staircase_legs: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class SteadyState:
    """The points of one file (thrust, voltage, native command, kind, whether the rotor was
    mostly stopped, the leg of a staircase read leg by leg: +1 up, -1 down, 0 none), the
    selection report and each sample's role."""

    thrust_n: FloatArray
    voltage_v: FloatArray
    command: FloatArray
    kinds: np.ndarray[Any, Any]
    at_rest: npt.NDArray[np.bool_]
    info: dict[str, Any]
    roles: npt.NDArray[np.int8]
    leg: npt.NDArray[np.int8]


@dataclass
class _Run:
    """One file's extraction as the rules run: its inputs, the stairs (command levels), the
    points found so far and the samples' roles."""

    ds: Dataset
    sel: Selection
    stopped: npt.NDArray[np.bool_]
    tol: float
    fresh: npt.NDArray[np.bool_]
    held: dict[str, Any]
    levels: list[tuple[int, int, int | None]]
    stairs: list[Stair]
    period: float
    rest_n: float
    #: stairs of 2+ rows (indices into ``stairs``) and those stairs
    candidates: list[int]
    sub: list[Stair]
    report: SteadyReport = field(default_factory=SteadyReport)
    t_out: list[float] = field(default_factory=list)
    b_out: list[float] = field(default_factory=list)
    th_out: list[float] = field(default_factory=list)
    kinds: list[str] = field(default_factory=list)
    point_at_rest: list[bool] = field(default_factory=list)
    leg_of: list[int] = field(default_factory=list)
    used: set[int] = field(default_factory=set)  # stairs already read (indices into ``stairs``)
    #: staircases whose stairs hold long enough after their transient: (up, down, turn)
    legged: list[tuple[list[int], list[int], int]] = field(default_factory=list)
    settled: dict[int, npt.NDArray[np.int64]] = field(default_factory=dict)
    roles: npt.NDArray[np.int8] = field(default_factory=lambda: np.zeros(0, dtype=np.int8))
    in_plateau: npt.NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, dtype=bool))

    @property
    def th(self) -> FloatArray:
        return self.ds.throttle_native

    def add(self, thrust_n: float, voltage_v: float, command: float, kind: str, at_rest: bool,
            leg: int = 0) -> None:  # fmt: skip
        self.t_out.append(thrust_n)
        self.b_out.append(voltage_v)
        self.th_out.append(command)
        self.kinds.append(kind)
        self.point_at_rest.append(at_rest)
        self.leg_of.append(leg)


def _prepare(ds: Dataset, sel: Selection, stopped: npt.NDArray[np.bool_]) -> _Run:
    """The file's command levels as stairs (row means from cumulative sums: one pass, however
    many levels a file has), the rest reading and the sensor's fresh updates."""
    th = ds.throttle_native
    tol = sel.plateau_tolerance_pct / 100.0 * ds.throttle_scale.span
    known = ds.meta.get("thrust_sensor") == SAMPLE_AND_HOLD
    fresh, held = sensor_updates(ds.thrust_n, th, tol, known)
    levels = plateau_levels(ds, tol)
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
    candidates = [i for i, st in enumerate(stairs) if st.b - st.a >= 2]
    return _Run(
        ds=ds,
        sel=sel,
        stopped=stopped,
        tol=tol,
        fresh=fresh,
        held=held,
        levels=levels,
        stairs=stairs,
        period=period,
        rest_n=float(np.median(at_rest_n)) if at_rest_n else 0.0,
        candidates=candidates,
        sub=[stairs[i] for i in candidates],
        roles=np.zeros(len(ds), dtype=np.int8),
        in_plateau=np.zeros(len(ds), dtype=bool),
    )


def _quasi_static_stairs(run: _Run) -> None:
    """Quasi-static staircases: legs whose stairs last only a few sensor updates (too short to
    settle and average) are a slow ramp seen through the sensor: up and down legs are paired.
    A leg pair is quasi-static when its stairs last fewer sensor updates than
    ``quasi_static_updates`` or less than ``quasi_static_lags`` times the lag seen between its
    legs (rotor + sensor): the transient never dies out inside a stair. Staircases whose stairs
    hold long enough are left to ``_staircase_legs`` (``run.legged``)."""
    ds, sel, sub = run.ds, run.sel, run.sub
    all_legs = stair_legs(sub, run.tol, sel.min_stair_legs)
    sub_at_rest = np.array([bool(run.stopped[st.a : st.b].mean() > 0.5) for st in sub], dtype=bool)
    legpairs = Paired()
    legs: list[list[int]] = []
    for (d1, l1), (d2, l2) in zip(all_legs, all_legs[1:], strict=False):
        if d1 == d2 or l2[0] - l1[-1] > 1:
            continue
        up_leg, down_leg = (l1, l2) if d1 > 0 else (l2, l1)
        for i in up_leg + down_leg:
            if i not in run.settled:
                run.settled[i] = settled_updates(ds.thrust_n, run.fresh, sub[i], sel.settle_sigmas)
        held_for = [len(run.settled[i]) for i in up_leg + down_leg if i != l1[-1]]
        if held_for and float(np.median(held_for)) >= sel.leg_plateau_updates:
            run.legged.append((up_leg, down_leg, l1[-1]))
            continue
        one = pair_legs(sub, up_leg, down_leg, l1[-1], run.rest_n, sel, sub_at_rest)
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
            run.report.turning_stairs_dropped_unsettled += 1
        _merge_pairs(legpairs, one)
    # legs of a staircase too short to settle that had no opposite leg to pair with: their lag
    # cannot be cancelled (run the staircase up and back down)
    paired_starts = {leg[0] for leg in legs}
    run.report.quasi_static_legs_unpaired = sum(
        1
        for _, leg in all_legs
        if leg[0] not in paired_starts
        and float(np.median([sub[i].updates for i in leg])) < sel.quasi_static_updates
    )
    _add_stair_pairs(run, legpairs)
    if legs:
        run.report.staircase = _staircase_summary(run, legs, legpairs.lag_s)


def _merge_pairs(into: Paired, one: Paired) -> None:
    """Add one leg pair's points and counts to the file's."""
    into.lag_s += one.lag_s
    into.thrust_n += one.thrust_n
    into.voltage_v += one.voltage_v
    into.command += one.command
    into.stairs += one.stairs
    into.used |= one.used
    into.stalled += one.stalled
    into.voltage_apart += one.voltage_apart


def _add_stair_pairs(run: _Run, legpairs: Paired) -> None:
    """The paired legs' points (kind ``stair-pair``) and the stairs they used."""
    run.used = {run.candidates[i] for i in legpairs.used}
    for (u, w), t, v, c in zip(
        legpairs.stairs, legpairs.thrust_n, legpairs.voltage_v, legpairs.command, strict=True
    ):
        su, sw = run.sub[u], run.sub[w]
        rows = np.r_[su.a : su.b, sw.a : sw.b]
        run.add(t, v, c, "stair-pair", bool(run.stopped[rows].mean() > 0.5))
        run.roles[rows] = ROLE_STAIR_PAIR
    for i in run.used:
        run.in_plateau[run.stairs[i].a : run.stairs[i].b] = True
    run.report.stair_pair_samples = sum(run.stairs[i].b - run.stairs[i].a for i in run.used)
    run.report.stair_pairs = len(legpairs.thrust_n)
    run.report.stair_pairs_dropped_stalled = legpairs.stalled
    run.report.stair_pairs_dropped_voltage_apart = legpairs.voltage_apart


def _staircase_summary(run: _Run, legs: list[list[int]], lag_s: list[float]) -> dict[str, Any]:
    """A quasi-static staircase's dwell, sensor updates per stair, legs and lag."""
    ds = run.ds
    leg_stairs = [run.sub[i] for leg in legs for i in leg]
    dwell = float(np.median([st.dwell for st in leg_stairs]))
    per_update = len(ds) / max(int(run.fresh.sum()), 1)
    staircase: dict[str, Any] = {
        "dwell_s" if ds.time_s is not None else "dwell_samples": round(dwell, 4),
        "dwell_sensor_updates": round(float(np.median([st.updates for st in leg_stairs])), 1),
        "legs": len(legs),
    }
    if ds.time_s is not None:
        staircase["sensor_update_s"] = round(per_update * run.period, 4)
    if lag_s and ds.time_s is not None:
        # rotor + sensor lag seen between the legs (a first-order time constant)
        staircase["lag_s"] = round(float(np.median(lag_s)), 4)
    return staircase


def _creep(run: _Run) -> tuple[FloatArray, dict[str, float]]:
    """The thrust as read, or corrected for a first-order load-cell creep that the legs'
    same-command stairs show (with what was found)."""
    same_command: list[tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]] = []
    for up_leg, down_leg, turn_i in run.legged:
        for u in up_leg:
            if u == turn_i:
                continue  # (the rest stairs at both ends pair too: unloaded, equal)
            for d in down_leg:
                if d != turn_i and abs(run.sub[d].command - run.sub[u].command) <= run.tol:
                    same_command.append((run.settled[u], run.settled[d]))
    found = creep_correction(run.ds.thrust_n, same_command, run.ds.voltage_v)
    if found is None:
        return run.ds.thrust_n, {}
    reading, creep = found
    if run.period > 0:
        creep["time_s"] = round(creep["time_rows"] * run.period, 3)
    return reading, creep


def _staircase_legs(run: _Run) -> None:
    """Staircases read leg by leg: a plateau per stair (its transient dropped, the rest
    averaged, a drift kept: it is what the legs' disagreement measures), the turning stair
    once; the legs' disagreement (and any creep read out) goes to the report."""
    if not run.legged:
        return
    reading, creep = _creep(run)
    d_cmd_all: list[float] = []
    d_thr_all: list[float] = []
    d_thr_raw: list[float] = []
    held_updates: list[int] = []
    for up_leg, down_leg, turn_i in run.legged:
        first = len(run.t_out)
        raw_of = _leg_plateaus(run, (up_leg, down_leg, turn_i), reading, held_updates)
        pct = np.asarray(run.ds.throttle_scale.to_pct(np.asarray(run.th_out[first:])))
        mine = np.asarray(run.leg_of[first:], dtype=np.int8)
        moving = ~np.asarray(run.point_at_rest[first:], dtype=bool)
        volts = np.asarray(run.b_out[first:])[moving]
        dc, dt_rel = legs_disagree(
            pct[moving], np.asarray(run.t_out[first:])[moving], volts, mine[moving]
        )
        d_cmd_all += dc
        d_thr_all += dt_rel
        d_thr_raw += legs_disagree(pct[moving], np.asarray(raw_of)[moving], volts, mine[moving])[1]
    abs_cmd = np.abs(np.asarray(d_cmd_all, dtype=float))
    legs_info: dict[str, Any] = {
        "legs": 2 * len(run.legged),
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
        legs_info["load_cell_creep"] = creep
    run.report.staircase_legs = legs_info


def _leg_plateaus(
    run: _Run,
    staircase: tuple[list[int], list[int], int],
    reading: FloatArray,
    held_updates: list[int],
) -> list[float]:
    """One staircase's stairs as plateaus (leg +1 up, -1 down, 0 the turning stair); returns
    their thrust as read before any creep correction."""
    up_leg, down_leg, turn_i = staircase
    raw_of: list[float] = []
    ds, th = run.ds, run.th
    for i, sign in [(i, 1) for i in up_leg] + [(i, -1) for i in down_leg if i != turn_i]:
        li = run.candidates[i]
        if li in run.used:
            continue
        st = run.sub[i]
        kept = run.settled[i]
        run.used.add(li)
        run.in_plateau[st.a : st.b] = True
        if len(kept) < 2:
            run.report.plateaus_dropped_unsettled += 1
            continue
        start = int(kept[0])
        held_updates.append(len(kept))
        run.report.plateau_samples += st.b - st.a
        run.report.settling_samples_dropped += start - st.a
        run.roles[st.a : start] = ROLE_SETTLING
        run.roles[start : st.b] = ROLE_PLATEAU
        raw_of.append(float(np.mean(ds.thrust_n[kept])))
        run.add(
            float(np.mean(reading[kept])),
            float(np.mean(ds.voltage_v[start : st.b])),
            float(np.mean(th[start : st.b])),
            "plateau",
            bool(run.stopped[start : st.b].mean() > 0.5),
            0 if i == turn_i else sign,
        )
    return raw_of


def _plateaus(run: _Run) -> None:
    """Every other command level with enough sensor updates: its settling dropped (from where
    the recorder saw it settled, else detected), a plateau that still trends dropped."""
    ds, sel, th = run.ds, run.sel, run.th
    for li, (a, b, settled_from) in enumerate(run.levels):
        if li in run.used:
            continue
        upd = a + np.flatnonzero(run.fresh[a:b])  # samples with a new thrust reading
        if len(upd) < sel.min_plateau_samples:
            continue
        run.in_plateau[a:b] = True
        if settled_from is not None:
            start = settled_from  # the recorder saw it settled from here: no guessing
            run.report.plateaus_settled_by_recorder += 1
        else:
            k = settle_index(ds.thrust_n[upd], sel.settle_sigmas)
            start = int(upd[k]) if k < len(upd) else b
        kept = upd[upd >= start]
        if len(kept) < 2:
            run.report.plateaus_dropped_unsettled += 1
            continue
        if still_trends(ds.thrust_n[kept], sel):
            run.report.plateaus_dropped_still_trending += 1
            continue
        run.report.plateau_samples += b - a
        run.report.settling_samples_dropped += start - a
        run.roles[a:start] = ROLE_SETTLING
        run.roles[start:b] = ROLE_PLATEAU
        run.add(
            float(np.mean(ds.thrust_n[kept])),
            float(np.mean(ds.voltage_v[start:b])),
            float(np.mean(th[start:b])),
            "plateau",
            bool(run.stopped[start:b].mean() > 0.5),
        )


def _ramps(run: _Run) -> None:
    """Ramps: each up-ramp paired with the down-ramp next to it (at the same throttle the rotor
    lags below on the way up and above on the way down, so the mean cancels the lag to first
    order); unpaired ramp samples kept only where the slew makes lag cheaper than the budget."""
    ds, sel, th = run.ds, run.sel, run.th
    if ds.time_s is None or len(ds) <= 2:
        return
    dt = np.gradient(ds.time_s)
    ok_dt = dt > 0
    dth = np.gradient(ds.throttle_pct)
    slew_pct_s = np.full(len(ds), np.inf)
    slew_pct_s[ok_dt] = np.abs(dth[ok_dt] / dt[ok_dt])
    on_ramp = (~run.in_plateau) & ok_dt & (slew_pct_s > 0) & np.isfinite(slew_pct_s)
    paired = np.zeros(len(ds), dtype=bool)
    for up, down in _ramp_pairs(on_ramp, dth, ds.time_s, sel.min_plateau_samples, sel.min_ramp_s):
        x_up, x_dn = th[up], th[down]
        order = np.argsort(x_dn)
        inside = (x_up >= x_dn.min()) & (x_up <= x_dn.max())
        if inside.sum() < 2:
            continue
        means = [
            (arr[up][inside] + np.interp(x_up[inside], x_dn[order], arr[down][order])) / 2.0
            for arr in (ds.thrust_n, ds.voltage_v)
        ]
        for t, v, c, stop in zip(
            means[0], means[1], x_up[inside], run.stopped[up[inside]], strict=True
        ):
            run.add(float(t), float(v), float(c), "ramp-pair", bool(stop))
        run.report.ramp_pair_points += int(inside.sum())
        paired[up[inside]] = True
        paired[down] = True
        run.roles[up[inside]] = ROLE_RAMP
        run.roles[down] = ROLE_RAMP
    quasi = on_ramp & ~paired & (slew_pct_s * sel.ramp_lag_s <= sel.lag_budget_pct)
    idx = np.flatnonzero(quasi)
    run.roles[idx] = ROLE_RAMP
    run.report.ramp_samples_kept = len(idx) + int(paired.sum())
    for k in idx:
        run.add(
            float(ds.thrust_n[k]),
            float(ds.voltage_v[k]),
            float(th[k]),
            "ramp",
            bool(run.stopped[k]),
        )


#: the rules, in order: each reads what the earlier ones left (stairs used, samples in plateaus)
RULES: tuple[Callable[[_Run], None], ...] = (
    _quasi_static_stairs,
    _staircase_legs,
    _plateaus,
    _ramps,
)


def _nothing_found(run: _Run) -> FitError:
    n_unpaired = run.report.quasi_static_legs_unpaired
    why = (
        f"; {n_unpaired} staircase leg{'s' if n_unpaired > 1 else ''} of stairs too short to "
        "settle had no opposite leg to cancel the lag (run it up and back down)"
        if n_unpaired
        else ""
    )
    return FitError(
        "no steady-state points found (no throttle plateau of "
        f"{run.sel.min_plateau_samples}+ samples, no slow ramp{why}); use --all-samples to fit "
        "raw samples",
        file=run.ds.path,
    )


def _info(run: _Run) -> dict[str, Any]:
    """The selection report: the counts, then only the rules' nonzero drops, the staircases."""
    r = run.report
    info: dict[str, Any] = {
        "plateaus": run.kinds.count("plateau"),
        "plateaus_settled_by_recorder": r.plateaus_settled_by_recorder,
        "plateau_samples": r.plateau_samples,
        "settling_samples_dropped": r.settling_samples_dropped,
        "ramp_samples_kept": r.ramp_samples_kept,
        "ramp_pair_points": r.ramp_pair_points,
        "stair_pair_samples": r.stair_pair_samples,
        "transient_samples_dropped": len(run.ds)
        - r.plateau_samples
        - r.ramp_samples_kept
        - r.stair_pair_samples,
        **run.held,
    }
    rules = {
        "plateaus_dropped_still_trending": r.plateaus_dropped_still_trending,
        "plateaus_dropped_unsettled": r.plateaus_dropped_unsettled,
        "stair_pairs": r.stair_pairs,
        "stair_pairs_dropped_stalled": r.stair_pairs_dropped_stalled,
        "stair_pairs_dropped_voltage_apart": r.stair_pairs_dropped_voltage_apart,
        "turning_stairs_dropped_unsettled": r.turning_stairs_dropped_unsettled,
        "quasi_static_legs_unpaired": r.quasi_static_legs_unpaired,
    }
    info.update({k: v for k, v in rules.items() if v})
    if r.staircase:
        info["quasi_static_staircase"] = r.staircase
    if r.staircase_legs:
        info["staircase_legs"] = r.staircase_legs
    short_rest = [
        st
        for i, st in enumerate(run.stairs)
        if i not in run.used
        and st.updates < run.sel.min_plateau_samples
        and run.ds.throttle_scale.to_pct(st.command) <= run.sel.plateau_tolerance_pct
    ]
    if short_rest:  # zero-command stairs too short to be points: still the rest reading
        info["tare_points"] = len(short_rest)
        info["tare_offset_n"] = round(run.rest_n, 6)
    return info


def steady_state(ds: Dataset, sel: Selection, stopped: npt.NDArray[np.bool_]) -> SteadyState:
    """The steady-state points of one file: ``RULES`` in order, then the report."""
    run = _prepare(ds, sel, stopped)
    for rule in RULES:
        rule(run)
    if not run.t_out:
        raise _nothing_found(run)
    return SteadyState(
        np.asarray(run.t_out),
        np.asarray(run.b_out),
        np.asarray(run.th_out),
        np.asarray(run.kinds),
        np.asarray(run.point_at_rest, dtype=bool),
        _info(run),
        run.roles,
        np.asarray(run.leg_of, dtype=np.int8),
    )
