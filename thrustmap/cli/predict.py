"""``thrustmap predict``: one answer from a map, and where it stands against the map's data and
the extrapolation benchmark's evidence (inside, extrapolated, or beyond the evidence)."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

import click

from thrustmap.cli.textwidth import echo
from thrustmap.core import physical
from thrustmap.core.errors import ConfigError
from thrustmap.fitting.extrapolation import COMMAND
from thrustmap.fitting.interval import Standing
from thrustmap.fitting.mapfile import ThrustMap, json_ready
from thrustmap.fitting.mapvalues import saturation_note, saturation_pct
from thrustmap.fitting.spinup import SpinUp

#: exit code of an answer the map cannot give (unreachable, beyond the evidence)
NO_ANSWER = 1


@dataclass(frozen=True)
class Query:
    thrust_n: float | None
    throttle_native: float | None
    throttle_pct: float | None
    voltage_v: float
    corrected: bool


def _json(obj: Any) -> str:
    return json.dumps(json_ready(obj), indent=2, allow_nan=False)


def _forward_pct(tmap: ThrustMap, q: Query) -> float:
    """The throttle given (% of the map's scale), checked to lie on the scale."""
    sc = tmap.throttle_scale
    native = q.throttle_native if q.throttle_native is not None else math.nan
    pct = float(q.throttle_pct if q.throttle_pct is not None else sc.to_pct(native))
    if not -1e-9 <= pct <= 100.0 + 1e-9:
        given_as = (
            f"--throttle-pct {q.throttle_pct:g}"
            if q.throttle_pct is not None
            else f"--throttle {q.throttle_native:g} ({pct:.1f} %)"
        )
        raise ConfigError(
            f"{given_as}: expected 0..100 % of the map's throttle scale "
            f"({sc.lo:g}..{sc.hi:g} {sc.unit_label})"
        )
    return pct


def _common(tmap: ThrustMap, t: float, q: Query) -> dict[str, Any]:
    region = tmap.supported_region()
    b = q.voltage_v
    g = float(tmap.model_thrust(1.0, b, corrected=q.corrected))  # γ(B), 1 uncorrected
    r_lo, r_hi = (float(x) / g for x in region.thrust_range(b))
    inside = bool(tmap.in_box(tmap.model_thrust(t, b, corrected=q.corrected), b))
    return {
        "thrust_n": t,
        "voltage_v": b,
        "throttle_unit": tmap.throttle_scale.unit,
        # inside the supported region (where the map's data are); the historical key is kept
        "inside_supported_region": inside,
        "inside_validity_box": inside,
        "supported_thrust_n": [r_lo, r_hi]
        if region.voltage_lo_v <= b <= region.voltage_hi_v
        else None,
        "corrected": q.corrected and tmap.correction is not None,
        # γ(B) applied at this voltage (None: no correction applied)
        "gamma": g if q.corrected and tmap.correction is not None else None,
    }


def _gamma_line(tmap: ThrustMap, common: dict[str, Any]) -> str | None:
    """The line that says the map's flight correction was applied (and whether forced)."""
    if common["gamma"] is None or tmap.correction is None:
        return None
    forced = tmap.correction.metrics.get("forced")
    return (
        f"flight correction applied: γ(B) = {common['gamma']:.4g} at {common['voltage_v']:.2f} V "
        f"(the bench map at γ·T; --no-correction for the bench map alone)"
        + (f"; γ was written with --force: {'; '.join(map(str, forced))}" if forced else "")
    )


def _evidence_fields(st: Standing) -> dict[str, Any]:
    d = st.to_dict()
    return {
        "extrapolated": d["extrapolated"],
        "thrust_reach_ratio": d["thrust_reach_ratio"],
        "voltage_log_distance": d["voltage_log_distance"],
        "beyond_evidence": d["beyond_evidence"],
        "beyond_evidence_reason": d["beyond_evidence_reason"],
        "evidence_limit": d["evidence_limit"],
    }


def _below_spin_up(tmap: ThrustMap, pct: float) -> str | None:
    """The note for a throttle below the measured spin-up: the rotor does not turn there (and a
    fraction typed as a percentage is named)."""
    spin = SpinUp.from_dict(tmap.spin_up)
    if spin is None or spin.throttle_pct is None or not 0.0 < pct < spin.throttle_pct:
        return None
    meant = f"; did you mean {pct * 100:g} %?" if pct < 1.0 else ""
    return (
        f"note: {pct:g} % is below the spin-up the stand measured ({spin.throttle_pct:.3g} %): the "
        f"rotor does not turn there, so its thrust is zero whatever the map's curve says{meant}"
    )


def _zero_thrust(tmap: ThrustMap, q: Query, as_json: bool) -> int:
    """Zero thrust is the motor below its spin-up: the answer is that command (measured on
    the stand when the map has it, else where the map's thrust reaches zero, else 0 %)."""
    sc = tmap.throttle_scale
    spin = SpinUp.from_dict(tmap.spin_up)
    at_zero = float(tmap.throttle_pct(0.0, q.voltage_v, corrected=q.corrected))
    if spin is not None and spin.throttle_pct is not None:
        pct, how = spin.throttle_pct, "the lowest command the stand saw spin the rotor (spin-up)"
    elif math.isfinite(at_zero) and 0.0 <= at_zero <= 100.0:
        pct, how = at_zero, "where the map's thrust reaches zero (the map has no measured spin-up)"
    else:
        pct, how = 0.0, "the motor stopped (the map has no measured spin-up)"
    result = {
        **_common(tmap, 0.0, q),
        "reachable": True,
        "zero_thrust": True,
        "throttle_pct": pct,
        "throttle_native": float(sc.from_pct(pct)),
        "throttle_meaning": f"zero thrust: every command up to this one gives none; {how}",
        "interval_pct": None,
    }
    if as_json:
        click.echo(_json(result))
    else:
        echo(
            f"zero thrust at {q.voltage_v:.2f} V: the rotor makes none up to throttle "
            f"{pct:.2f} % = {float(sc.from_pct(pct)):.2f} {sc.unit_label}, {how}"
        )
    return 0


def _unreachable(
    tmap: ThrustMap, q: Query, t: float, pct: float, top_pct: float, as_json: bool
) -> int:
    """The motor cannot make this thrust at this voltage (per the map): no answer. ``top_pct``:
    the highest command that still adds thrust (100, or where the ESC saturated)."""
    edge = top_pct if pct > top_pct else 0.0
    nearest = float(tmap.thrust_n(edge, q.voltage_v, corrected=q.corrected))
    common = _common(tmap, t, q)
    result = {
        **common,
        "reachable": False,
        "throttle_pct": None,
        "throttle_native": None,
        "required_throttle_pct": pct,
        "nearest_reachable_thrust_n": nearest,
        "nearest_reachable_throttle_pct": edge,
    }
    if edge and edge < 100.0:
        result["saturated_above_pct"] = edge
    if as_json:
        click.echo(_json(result))
        return NO_ANSWER
    why = f"; {saturation_note(tmap, pct)}" if edge and edge < 100.0 else ""
    echo(
        f"unreachable: T={t:.4f} N at {q.voltage_v:.2f} V would need "
        f"{f'more than {edge:.4g}' if edge else 'less than 0'} % of the throttle scale "
        f"({pct:.1f} % by the map){why}; the nearest reachable thrust at {q.voltage_v:.2f} V is "
        f"{nearest:.4f} N (throttle {edge:.4g} %)"
    )
    if line := _gamma_line(tmap, common):
        click.echo(line)
    return NO_ANSWER


def _refuse(common: dict[str, Any], st: Standing, as_json: bool) -> int:
    """Beyond the evidence without --extrapolate: no answer, saying how far and the limit."""
    reason = st.beyond_evidence or ""
    if as_json:
        click.echo(_json({**common, "throttle_pct": None, **_evidence_fields(st)}))
        return NO_ANSWER
    echo(
        f"beyond the evidence: T={common['thrust_n']:.4f} N at {common['voltage_v']:.2f} V: "
        f"{reason}; no benchmark shows the map's interval holds there ({COMMAND}); "
        "--extrapolate answers anyway"
    )
    return NO_ANSWER


def _where_note(tmap: ThrustMap, common: dict[str, Any], st: Standing, base: float | None) -> str:
    """The warning for an answer outside the supported region (stderr)."""
    b = common["voltage_v"]
    region = tmap.supported_region()
    if common["supported_thrust_n"] is not None:
        r_lo, r_hi = common["supported_thrust_n"]
        where = f"at {b:.2f} V the data reach T {r_lo:.3f}..{r_hi:.3f} N"
    else:
        where = f"the data span B {region.voltage_lo_v:.2f}..{region.voltage_hi_v:.2f} V"
    half = st.half_width_pct
    if half is None or base is None:
        widened = ""
    elif half > 1.005 * base:
        widened = f"; interval widened ×{half / base:.2f}, from ±{base:.2f} % to ±{half:.2f} %"
    else:  # the distance is in voltage only: its share (κ) is already in the interval
        widened = f"; its interval there is ±{half:.2f} % (the voltage distance included)"
    if st.beyond_evidence:
        how_far = f"beyond the evidence (--extrapolate): {st.beyond_evidence}"
    else:
        how_far = (
            f"within the evidence (T/reach {st.thrust_reach_ratio:.2f} of at most "
            f"{st.limit_thrust_ratio:.2f}, |ln(B/B_measured)| {st.voltage_log_distance:.2f} of at "
            f"most {st.limit_voltage_log:.2f})"
        )
    return (
        f"warning: T={common['thrust_n']:.3f} N, B={b:.2f} V is outside the map's supported "
        f"region ({where}): extrapolated {how_far}{widened}"
    )


def run_predict(map_file: str, q: Query, *, extrapolate: bool, as_json: bool) -> int:
    """The command's work after its options are checked; returns the exit code."""
    tmap = ThrustMap.load(map_file)
    _check_pack(tmap, q.voltage_v)
    sc = tmap.throttle_scale
    top_pct = saturation_pct(tmap) or 100.0
    if q.thrust_n is None:
        pct = _forward_pct(tmap, q)
        t = float(tmap.thrust_n(min(pct, top_pct), q.voltage_v, corrected=q.corrected))
        if note := _below_spin_up(tmap, pct):
            echo(note, err=True)
        if pct > top_pct:
            echo(f"note: {saturation_note(tmap, pct)}", err=True)
    elif q.thrust_n == 0.0:
        return _zero_thrust(tmap, q, as_json)
    else:
        t = q.thrust_n
        pct = float(tmap.throttle_pct(t, q.voltage_v, corrected=q.corrected))
    if not (math.isfinite(pct) and math.isfinite(t)):
        raise ConfigError(f"the map gives no finite answer at T={t:g} N, B={q.voltage_v:g} V")
    if q.thrust_n is not None and not 0.0 <= pct <= top_pct:
        return _unreachable(tmap, q, t, pct, top_pct, as_json)
    common = _common(tmap, t, q)
    st = tmap.standing(t, q.voltage_v, corrected=q.corrected)
    if st.beyond_evidence and not extrapolate:
        return _refuse(common, st, as_json)
    parts = tmap.interval_parts(t, q.voltage_v, corrected=q.corrected)
    base = None if parts is None else float(parts[0])
    half = st.half_width_pct
    interval = tmap.prediction_interval()
    result = {
        **common,
        "reachable": True,
        "throttle_pct": pct,
        "throttle_native": float(sc.from_pct(pct)),
        # half-width of the map's prediction interval in throttle % (None: the map has none)
        "interval_pct": half,
        "interval_native": None if half is None else half * sc.span / 100.0,
        "interval_level": None if interval is None else interval.level,
        # how much the interval widened for the distance outside the supported region
        "interval_widening": None if half is None or not base else half / base,
        "interval_at_region_pct": base,
        **_evidence_fields(st),
    }
    thrust_line = None
    if q.thrust_n is None:
        forward = tmap if q.corrected else tmap.with_correction(None)
        thrust_line = _forward_thrust(forward, pct, q.voltage_v, result)
        if pct > top_pct:
            result["saturated_above_pct"] = top_pct
    if not st.inside:
        echo(_where_note(tmap, common, st, base), err=True)
    if as_json:
        click.echo(_json(result))
        return 0
    pm = "" if half is None else f" ± {half:.2f}"
    pm_native = "" if half is None else f" ± {half * sc.span / 100.0:.2f}"
    level = "" if interval is None else f" ({100 * interval.level:.0f} % prediction interval)"
    tag = (
        "" if st.inside else (" [beyond the evidence]" if st.beyond_evidence else " [extrapolated]")
    )
    echo(
        f"thrust {t:.4f} N at {q.voltage_v:.2f} V  <->  throttle {pct:.3f}{pm} % = "
        f"{float(sc.from_pct(pct)):.2f}{pm_native} {sc.unit_label}{level}{tag}"
    )
    if thrust_line:
        click.echo(thrust_line)
    if line := _gamma_line(tmap, common):
        click.echo(line)
    return 0


def _check_pack(tmap: ThrustMap, voltage_v: float) -> None:
    """Refuse a voltage that is one cell of the map's pack (or a whole pack given to a
    per-cell map); say which pack a one-cell map's voltages were read as."""
    box = tmap.validity.voltage_v
    problem = physical.voltage_against_pack(voltage_v, box.lo, box.hi)
    if problem is not None:
        raise ConfigError(problem)
    assumed = physical.pack_assumed(box.lo, box.hi)
    if assumed is not None:
        echo(f"note: {assumed}", err=True)
    other = physical.other_pack_note(voltage_v, box.lo, box.hi)
    if other is not None:
        echo(other, err=True)


def _forward_thrust(tmap: ThrustMap, pct: float, voltage_v: float, result: dict[str, Any]) -> str:
    """The thrust at a throttle as every export writes it (``fitting.mapvalues``): its 95 %
    interval in N and whether it is extrapolated, added to ``result``; the line to print."""
    from thrustmap.core.errors import FitError
    from thrustmap.fitting.mapvalues import thrust_at_command

    try:
        v = thrust_at_command(tmap, pct, voltage_v, key="thrust_n", name="thrust")
    except FitError as exc:
        result["thrust_interval_n"] = None
        return f"  thrust interval: {exc}"
    result["thrust_interval_n"] = None if v.lo is None else [v.lo, v.hi]
    result["thrust_extrapolated"] = v.extrapolated
    return f"  {v.line()}"
