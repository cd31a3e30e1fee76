"""The encoding export: a map's exact coefficients in one throttle encoding, as a small YAML
document (``thrustmap export MAP --to dshot``); Crazyflie encodings also carry seed 2's
linearisation. It builds on ``encodings`` (the exact rescaling) and ``platforms`` (the
Crazyflie polynomial), so neither of those imports the other."""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from thrustmap.core.units import ThrottleScale
from thrustmap.fitting.export.encodings import (
    ExportOptions,
    ExportResult,
    comment,
    export_values,
    header_lines,
    map_samples,
    reference_voltage,
    rescale,
)
from thrustmap.fitting.export.platforms import crazyflie_seed2
from thrustmap.fitting.mapfile import ThrustMap
from thrustmap.fitting.mapvalues import MapValues


def _num(x: float) -> str:
    return repr(float(x))


def _values_yaml(mv: MapValues, scale: ThrottleScale) -> str:
    """The map's values (``fitting.mapvalues``) as a YAML block: value, 95 % interval (null:
    none; .inf: unbounded), extrapolated; throttle values also in this encoding's units."""

    def num(x: float | None) -> str:
        if x is None:
            return "null"
        return ".inf" if x == float("inf") else _num(x)

    out = ["map_values:  # computed once from the map; the same in every export and predict\n"]
    for v in mv.all():
        out.append(
            f"  {v.key}: {{value: {num(v.value)}, interval_95: [{num(v.lo)}, {num(v.hi)}], "
            f"unit: {json.dumps(v.unit)}, voltage_v: {num(v.voltage_v)}, "
            f"extrapolated: {'true' if v.extrapolated else 'false'}"
        )
        if v.unit == "%":
            out.append(f", {scale.name}: {num(float(scale.from_pct(v.value)))}")
        out.append("}\n")
    return "".join(out)


def export_encoding(
    tmap: ThrustMap, scale: ThrottleScale, options: ExportOptions | None = None
) -> ExportResult:
    """Coefficients in ``scale``; Crazyflie scales also carry seed 2's linearisation."""
    opts = options or ExportOptions()
    enc = rescale(tmap, scale)
    extra_residual: list[str] = []
    extra_text = ""
    values: dict[str, Any] = {}
    b_ref = reference_voltage(tmap, opts.voltage_v)
    mv = export_values(tmap, scale, opts, b_ref)
    if scale.name in ("crazyflie", "crazyflie-cmd"):
        full_n = None if mv.full_throttle is None else mv.full_throttle.value
        cf = crazyflie_seed2(tmap, scale, opts, full_n)
        extra_residual, extra_text, values = cf.residual_lines, cf.text, {"seed2": cf}
    # Show the identity on the box: exported coefficients vs map-then-convert.
    s = map_samples(tmap, n_thrust=21, n_voltage=5)
    direct = scale.from_pct(s.throttle_pct)
    via = enc.evaluate(s.thrust_n, s.voltage_v)
    dev = float(np.max(np.abs(via - direct)) / max(scale.span, 1e-300))
    m = tmap.model_def
    names = list(m.term_names)
    lines = header_lines(
        tmap,
        f"coefficients in encoding {scale.name} {scale.lo:g}..{scale.hi:g} {scale.unit}",
        [
            "0 (exact affine rescaling of the map; evaluating these coefficients matches "
            f"map-then-convert to {dev:.1e} of the range on the validity box)",
            *extra_residual,
        ],
        mv,
    )
    out = [comment(lines, "#")]
    box = tmap.validity
    out.append(f"format: thrustmap.export.encoding\nversion: 1\nencoding: {scale.name}\n")
    out.append(f"unit: {json.dumps(scale.unit)}\nrange: [{_num(scale.lo)}, {_num(scale.hi)}]\n")
    out.append(f"model: {tmap.model}\n")
    formula = f"throttle_{scale.unit} = offset + " + " + ".join(
        f"c{k}*{n}" for k, n in enumerate(names)
    )
    if tmap.correction is not None:
        formula += "   with T replaced by gamma(B)*T"
    out.append(f"formula: {json.dumps(formula)}\n")
    out.append(f"terms: {json.dumps(names)}\n")
    out.append(f"offset: {_num(enc.offset)}\n")
    out.append("coefficients: [" + ", ".join(_num(c) for c in enc.coefficients) + "]\n")
    if m.uses_voltage or tmap.correction is not None:
        out.append("inputs: {thrust: N per rotor, voltage: V}\n")
    else:
        out.append("inputs: {thrust: N per rotor}\n")
    out.append(
        "validity:\n"
        f"  thrust_n: [{_num(box.thrust_n.lo)}, {_num(box.thrust_n.hi)}]\n"
        f"  voltage_v: [{_num(box.voltage_v.lo)}, {_num(box.voltage_v.hi)}]\n"
        f"  throttle: [{_num(float(scale.from_pct(box.throttle_pct.lo)))}, "
        f"{_num(float(scale.from_pct(box.throttle_pct.hi)))}]\n"
    )
    if tmap.correction is not None:
        g = tmap.correction
        out.append(
            "gamma:\n"
            '  formula: "gamma = sum(g[k] * B^k), B clamped to voltage_v"\n'
            "  coefficients: [" + ", ".join(_num(c) for c in g.coefficients) + "]\n"
            f"  voltage_v: [{_num(g.voltage_v.lo)}, {_num(g.voltage_v.hi)}]\n"
        )
    out.append(extra_text)
    out.append(_values_yaml(mv, scale))
    if mv.full_throttle is not None:
        values["full_throttle_thrust_n"] = mv.full_throttle.value
    values["map_values"] = mv
    values.update({"offset": enc.offset, "coefficients": enc.coefficients, "encoded": enc})
    return ExportResult(
        target=scale.name,
        text="".join(out),
        values=values,
        residual={"max_dev_of_range": dev},
        suffix=".yaml",
    )
