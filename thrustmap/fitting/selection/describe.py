"""One line on what selection did with a staircase, for the CLI and the report."""

from __future__ import annotations

from typing import Any


def describe_legs(legs: dict[str, Any]) -> str:
    """One line on a staircase read leg by leg: its points, the legs' disagreement, a creep."""
    line = (
        f"staircase read leg by leg: {legs.get('legs', 0)} legs, a plateau per stair "
        f"({legs.get('dwell_sensor_updates_settled', 0):g} sensor updates after the transient); "
        f"the legs disagree by {legs.get('disagreement_median_pct', 0.0):.2f} % throttle at equal "
        f"thrust (95th percentile {legs.get('disagreement_p95_pct', 0.0):.2f} %, half of it "
        "carried in the map's interval)"
    )
    creep = legs.get("load_cell_creep")
    if isinstance(creep, dict):
        when = (
            f"{creep['time_s']:g} s" if "time_s" in creep else f"{creep.get('time_rows', 0):g} rows"
        )
        line += (
            f"; a creeping load cell read out first ({100 * creep.get('fraction', 0.0):.0f} % of "
            f"each load change arriving over {when}: the legs disagreed by "
            f"{creep.get('thrust_disagreement_before_median_pct', 0.0):g} % in thrust before)"
        )
    return line


def describe(report: dict[str, Any]) -> str | None:
    """One line on a quasi-static staircase (what was paired and kept), or on a staircase read
    leg by leg, or None."""
    legs = report.get("staircase_legs")
    if isinstance(legs, dict):
        return describe_legs(legs)
    q = report.get("quasi_static_staircase")
    if not isinstance(q, dict):
        n = report.get("quasi_static_legs_unpaired", 0)
        if n:
            return (
                f"quasi-static staircase: {n} leg{'s' if n > 1 else ''} of stairs too short to "
                "settle, with no opposite leg to pair with: the lag cannot be cancelled and "
                "those stairs were dropped (run the staircase up and back down)"
            )
        return None
    if "dwell_s" in q:
        dwell = f"stairs of {q['dwell_s']:.3f} s"
    else:
        dwell = f"stairs of {q.get('dwell_samples', 0):g} samples"
    dwell += f" = {q.get('dwell_sensor_updates', 0):g} sensor updates"
    if "sensor_update_s" in q:
        dwell += f" (one every {q['sensor_update_s']:.3f} s)"
    lag = f", lag between the legs {q['lag_s'] * 1000:.0f} ms" if "lag_s" in q else ""
    kept = ""
    if "kept_thrust_n" in q:
        lo, hi = q["kept_thrust_n"]
        kept = f", kept {lo:.3f}..{hi:.3f} N ({q.get('thrust_range_kept_pct', 0):g} % of the thrust reached)"
    dropped = [
        f"{report[k]} {what}"
        for k, what in (
            ("stair_pairs_dropped_stalled", "with the rotor not turning on one leg"),
            ("stair_pairs_dropped_voltage_apart", "with the legs' voltages apart"),
        )
        if report.get(k)
    ]
    unpaired = report.get("quasi_static_legs_unpaired", 0)
    if unpaired:
        dropped.append(
            f"{unpaired} leg{'s' if unpaired > 1 else ''} without an opposite leg (lag not "
            "cancelled: run the staircase up and back down)"
        )
    return (
        f"quasi-static staircase: {dwell}{lag}; {q.get('legs', 0)} legs paired up/down at equal "
        f"command so the lag cancels: {report.get('stair_pairs', 0)} points{kept}"
        + (f"; dropped {', '.join(dropped)}" if dropped else "")
    )
