"""A creeping load cell: the share of a load change that arrives late and its time constant,
found where a staircase's legs agree best, and the thrust read through it."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from thrustmap.fitting.dataset import FloatArray

#: load-cell creep candidates: the share of a load change that arrives late, and its time
#: constant in rows (``creep_correction``)
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


def creep_correction(
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
