"""Plateaus: runs of one command, where each level begins (or where the recorder saw it
settle), when the thrust has settled inside its noise, which samples carry a new sensor
reading (a sample-and-hold load cell), and whether a kept part still trends."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from thrustmap.fitting.dataset import Dataset, FloatArray
from thrustmap.fitting.selection.options import Selection


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


def plateau_levels(ds: Dataset, tol: float) -> list[tuple[int, int, int | None]]:
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


def settle_index(thrust: FloatArray, sigmas: float) -> int:
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


def settle_index_detrended(y: FloatArray, sigmas: float) -> int:
    """First index from which ``y`` stays within its noise band of the straight line through
    its second half: a stair's transient (rotor lag, a conversion straddling the step), told
    from a slow drift (a creeping load cell) that goes on for the whole stair."""
    n = len(y)
    if n < 4:
        return settle_index(y, sigmas)
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


def sensor_updates(
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


def still_trends(y: FloatArray, sel: Selection) -> bool:
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


def row_period(ds: Dataset) -> float:
    """The log's median sample period (s), 0 without time."""
    if ds.time_s is None or len(ds) < 2:
        return 0.0
    d = np.diff(ds.time_s)
    d = d[d > 0]
    return float(np.median(d)) if d.size else 0.0
