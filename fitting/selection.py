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
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from thrustmap.errors import FitError
from thrustmap.fitting.dataset import STEP_SUMMARY, Dataset, FloatArray

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

    def to_dict(self) -> dict[str, Any]:
        return {
            "throttle_range": self.throttle_range,
            "voltage_range": self.voltage_range,
            "thrust_range": self.thrust_range,
            "all_samples": self.all_samples,
            "plateau_tolerance_pct": self.plateau_tolerance_pct,
            "settle_sigmas": self.settle_sigmas,
            "lag_budget_pct": self.lag_budget_pct,
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
    elif ds.meta.get("layout") == STEP_SUMMARY:
        # The stand software already averaged each step: every row is a steady-state point.
        t, b, th = ds.thrust_n, ds.voltage_v, ds.throttle_native
        kind = np.full(len(ds), "step-summary")
        report.update({"layout": STEP_SUMMARY, "step_summary_rows": len(ds)})
    else:
        t, b, th, kind, info = _steady_state(ds, sel)
        report.update(info)
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


def _steady_state(
    ds: Dataset, sel: Selection
) -> tuple[FloatArray, FloatArray, FloatArray, np.ndarray[Any, Any], dict[str, Any]]:
    th = ds.throttle_native
    tol = sel.plateau_tolerance_pct / 100.0 * ds.throttle_scale.span
    t_out: list[float] = []
    b_out: list[float] = []
    th_out: list[float] = []
    kinds: list[str] = []
    n_plateau_samples = n_settle_dropped = n_ramp_kept = 0
    in_plateau = np.zeros(len(ds), dtype=bool)
    n_runner_settled = 0
    for a, b, settled_from in _levels(ds, tol):
        if b - a < sel.min_plateau_samples:
            continue
        in_plateau[a:b] = True
        if settled_from is not None:
            k = settled_from - a  # the recorder saw it settled from here: no guessing
            n_runner_settled += 1
        else:
            k = _settle_index(ds.thrust_n[a:b], sel.settle_sigmas)
        if b - a - k < 2:
            continue
        n_plateau_samples += b - a
        n_settle_dropped += k
        t_out.append(float(np.mean(ds.thrust_n[a + k : b])))
        b_out.append(float(np.mean(ds.voltage_v[a + k : b])))
        th_out.append(float(np.mean(th[a + k : b])))
        kinds.append("plateau")
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
    }
    return (
        np.asarray(t_out),
        np.asarray(b_out),
        np.asarray(th_out),
        np.asarray(kinds),
        info,
    )
