"""Staircases: stairs and their monotone legs, up and down legs paired at equal command so
the lag cancels (quasi-static stairs), and the legs' disagreement when each stair settles."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from thrustmap.fitting.dataset import FloatArray
from thrustmap.fitting.selection.options import Selection
from thrustmap.fitting.selection.plateaus import settle_index_detrended


@dataclass(frozen=True)
class Stair:
    """One command level: [a, b), its command, row-mean thrust and voltage, fresh updates and
    dwell (s when the log has time, else rows)."""

    a: int
    b: int
    command: float
    thrust_n: float
    voltage_v: float
    updates: int
    dwell: float


def settled_updates(
    thrust: FloatArray, fresh: npt.NDArray[np.bool_], st: Stair, sigmas: float
) -> npt.NDArray[np.int64]:
    """The samples of a stair that carry a new sensor reading after its transient."""
    upd = st.a + np.flatnonzero(fresh[st.a : st.b])
    if len(upd) < 2:
        return upd[:0]
    return np.asarray(upd[settle_index_detrended(thrust[upd], sigmas) :], dtype=np.int64)


def stair_legs(stairs: list[Stair], tol: float, min_legs: int) -> list[tuple[int, list[int]]]:
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


def _leg_rate(stairs: list[Stair], leg: list[int]) -> float:
    """How fast a leg moves: median command step over median dwell (per s, or per row)."""
    steps = [abs(stairs[j].command - stairs[i].command) for i, j in zip(leg, leg[1:], strict=False)]
    dwell = float(np.median([stairs[i].dwell for i in leg[1:-1] or leg]))
    return float(np.median(steps)) / max(dwell, 1e-9)


@dataclass
class Paired:
    """Up/down leg pairs at equal command: points and what the pairing saw."""

    thrust_n: list[float] = field(default_factory=list)
    voltage_v: list[float] = field(default_factory=list)
    command: list[float] = field(default_factory=list)
    stairs: list[tuple[int, int]] = field(default_factory=list)  # (up stair, down stair near)
    used: set[int] = field(default_factory=set)
    stalled: int = 0
    voltage_apart: int = 0
    lag_s: list[float] = field(default_factory=list)


def pair_legs(
    stairs: list[Stair],
    up: list[int],
    down: list[int],
    turn: int,
    rest_n: float,
    sel: Selection,
    at_rest: npt.NDArray[np.bool_],
) -> Paired:
    """Pair each up-leg stair with the adjacent down leg read at the same command.

    Rotor and load cell lag low on the way up and high on the way down. With a first-order lag
    the error is proportional to how fast the leg moves, so the two readings are weighted by the
    other leg's rate (equal rates: the plain mean) and the lag cancels to first order. The down
    leg is interpolated at the up stair's command (its levels need not match); the turning stair
    has no counterpart and is not paired with itself. The down leg is later, so the battery has
    sagged further: a pair whose voltages differ by more than ``pair_voltage_rel`` is dropped.
    The lag left between the legs is reported (s, when the log has time)."""
    out = Paired()
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


def legs_disagree(
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
