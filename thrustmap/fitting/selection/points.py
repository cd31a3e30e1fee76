"""``select``: from a file's samples to its fit points (steady state, the rotor at rest,
the load cell's zero, the range filters), and ``Points``, what it returns."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from thrustmap.fitting.dataset import STEP_SUMMARY, Dataset, FloatArray
from thrustmap.fitting.selection.options import Selection
from thrustmap.fitting.selection.rest import rest_zero, rotor_stopped, th_pct_le
from thrustmap.fitting.selection.steady import steady_state
from thrustmap.fitting.selection.top import past_the_top


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
            stopped = rotor_stopped(ds, sel)
            t, b, th = ds.thrust_n, ds.voltage_v, ds.throttle_native
            kind = np.full(len(ds), "step-summary")
            report.update({"layout": STEP_SUMMARY, "step_summary_rows": len(ds)})
        else:
            found = steady_state(ds, sel, rotor_stopped(ds, sel))
            t, b, th, kind = found.thrust_n, found.voltage_v, found.command, found.kinds
            stopped, info, roles, leg = found.at_rest, found.info, found.roles, found.leg
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
    report["dropped_by_range"] = int((~keep).sum())
    if not sel.keep_past_top:
        cut = past_the_top(ds.throttle_scale.to_pct(th[keep]), t[keep], b[keep])
        if cut is not None:
            # past the top, throttle is no function of thrust: not map points (selection.top)
            keep[np.flatnonzero(keep)[cut.past]] = False
            report["past_top"] = cut.to_dict()
    report["kept_points"] = int(keep.sum())
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
