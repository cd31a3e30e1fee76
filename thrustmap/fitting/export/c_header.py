"""C header export: the exact map plus an allocation-free evaluator any firmware can call.

Entry point: ``float thrustmap_throttle(float thrust_n, float voltage_v)`` returning throttle in
the chosen encoding's units. It clamps thrust and voltage to the map's validity box, applies γ
when the map has one, evaluates the map and clamps the result to the encoding's range.

Accuracy. A raw-monomial polynomial at B ≈ 25 V cancels badly (terms of 1e4 summing to 1e2),
which float32 cannot survive. The header therefore re-centres polynomials exactly (rational
arithmetic on the stored doubles) onto u = T/Ts and v = (B − Bc)/Bs, with Ts and Bs powers of two
and Bc a multiple of 1/64 V, so the scaling adds no rounding and the terms are of the size of the
result. The working type is double by default (``THRUSTMAP_REAL``); define ``THRUSTMAP_USE_FLOAT``
before including for float32-only FPUs. Measured against Python on a grid over and beyond the box
(tests/test_export_c_header.py, poly2..poly4, motor, LA): double agrees to the float return
value's rounding (≤ 6.5e-8 of the output range), float to ≤ 2.8e-7 of the range; the same poly4
evaluated in float32 on raw monomials is off by 1e-5 of the range.
"""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import numpy.typing as npt

from thrustmap.core.errors import ConfigError
from thrustmap.core.units import ThrottleScale
from thrustmap.fitting.export.encodings import (
    ExportOptions,
    ExportResult,
    comment,
    export_values,
    header_lines,
    reference_voltage,
    target_scale,
)
from thrustmap.fitting.export.rules import C_HEADER
from thrustmap.fitting.mapfile import ThrustMap
from thrustmap.fitting.mapvalues import MapValues
from thrustmap.fitting.models import LinearTmaxModel, PolyModel

FloatArray = npt.NDArray[np.float64]


def reference_throttle(
    tmap: ThrustMap, scale: ThrottleScale, thrust_n: npt.ArrayLike, voltage_v: npt.ArrayLike
) -> FloatArray:
    """What the header computes, in Python: clamp inputs to the box, map, convert, clamp."""
    box = tmap.validity
    t = np.clip(np.asarray(thrust_n, float), box.thrust_n.lo, box.thrust_n.hi)
    b = np.clip(np.asarray(voltage_v, float), box.voltage_v.lo, box.voltage_v.hi)
    native = scale.from_pct(tmap.throttle_pct(t, b))
    return np.asarray(np.clip(native, scale.lo, scale.hi), dtype=float)


def _pow2_at_least(x: float) -> Fraction:
    if not x > 0:
        return Fraction(1)
    return Fraction(2) ** math.ceil(math.log2(x))


def _lit(x: Fraction | float) -> str:
    return f"THRUSTMAP_C({float(x):.17g})"


def _recentre(
    raw: dict[tuple[int, int], Fraction], ts: Fraction, bc: Fraction, bs: Fraction
) -> dict[tuple[int, int], Fraction]:
    """Σ r_ij T^i B^j  ->  Σ d_ik u^i v^k with T = ts·u, B = bc + bs·v (exact)."""
    out: dict[tuple[int, int], Fraction] = {}
    for (i, j), r in raw.items():
        for k in range(j + 1):
            w = r * ts**i * math.comb(j, k) * bc ** (j - k) * bs**k
            out[(i, k)] = out.get((i, k), Fraction(0)) + w
    return out


def _poly_body(
    tmap: ThrustMap, scale: ThrottleScale, bc: Fraction, bs: Fraction
) -> tuple[list[str], list[str]]:
    model = tmap.model_def
    assert isinstance(model, PolyModel)
    gain = Fraction(scale.hi) / 100 - Fraction(scale.lo) / 100
    raw: dict[tuple[int, int], Fraction] = {}
    for (i, j), c in zip(model.powers, tmap.coefficients, strict=True):
        raw[(i, j)] = raw.get((i, j), Fraction(0)) + gain * Fraction(c)
    raw[(0, 0)] = raw.get((0, 0), Fraction(0)) + Fraction(scale.lo)
    ts = _pow2_at_least(tmap.validity.thrust_n.hi)
    d = _recentre(raw, ts, bc, bs)
    deg_t = max(i for i, _ in d)
    deg_b = max(k for _, k in d)
    defines = [f"#define THRUSTMAP_TS_N {float(ts):.17g} /* thrust scale (power of two) */"]
    body = [
        f"    THRUSTMAP_REAL u = t * THRUSTMAP_C({float(1 / ts):.17g});",
        f"    THRUSTMAP_REAL up[{deg_t + 1}], vp[{deg_b + 1}];",
        "    up[0] = THRUSTMAP_C(1.0);",
        "    vp[0] = THRUSTMAP_C(1.0);",
    ]
    body += [f"    up[{i}] = up[{i - 1}] * u;" for i in range(1, deg_t + 1)]
    body += [f"    vp[{k}] = vp[{k - 1}] * v;" for k in range(1, deg_b + 1)]
    body.append("    THRUSTMAP_REAL r = THRUSTMAP_C(0.0);")
    for (i, k), dik in sorted(d.items(), key=lambda kv: (-(kv[0][0] + kv[0][1]), kv[0])):
        if dik == 0:
            continue
        body.append(f"    r += {_lit(dik)} * up[{i}] * vp[{k}];")
    return defines, body


def _motor_body(tmap: ThrustMap, scale: ThrottleScale) -> list[str]:
    gain = scale.span / 100.0
    c, k0, k1, k2 = tmap.coefficients
    return [
        "    THRUSTMAP_REAL st = t > THRUSTMAP_C(0.0) ? THRUSTMAP_SQRT(t) : THRUSTMAP_C(0.0);",
        f"    THRUSTMAP_REAL r = {_lit(scale.lo + gain * c)}",
        f"        + ({_lit(gain * k0)} + {_lit(gain * k1)} * st + {_lit(gain * k2)} * t) / b;",
    ]


def c_header_text(tmap: ThrustMap, scale: ThrottleScale, values: MapValues | None = None) -> str:
    model = tmap.model_def
    box = tmap.validity
    bc = Fraction(round((box.voltage_v.lo + box.voltage_v.hi) / 2 * 64), 64)
    half = (box.voltage_v.hi - box.voltage_v.lo) / 2
    bs = _pow2_at_least(half) if half > 0 else Fraction(1)
    uses_b = model.uses_voltage or tmap.correction is not None
    defines: list[str] = []
    if isinstance(model, PolyModel):
        defines, body = _poly_body(tmap, scale, bc, bs)
    elif tmap.model == "motor":
        body = _motor_body(tmap, scale)
    elif isinstance(model, LinearTmaxModel):
        gain = scale.span / 100.0
        body = [
            f"    THRUSTMAP_REAL r = {_lit(scale.lo)} + {_lit(gain * tmap.coefficients[0])} * t;"
        ]
    else:
        raise ConfigError(f"c-header export does not know how to write model '{tmap.model}'")

    lines = header_lines(
        tmap,
        f"C header, throttle in {scale.name} {scale.lo:g}..{scale.hi:g} {scale.unit}",
        [
            "0 for the map form (exact coefficients, re-centred exactly); compiled, it agrees with "
            "the map to the float return value's rounding (double) or ~3e-7 of the range (float)",
        ],
        values,
    )
    lines.append(f"firmware: {C_HEADER.header()}; it replaces no firmware default")
    lines += [
        "",
        "float thrustmap_throttle(float thrust_n, float voltage_v): thrust per rotor [N], battery",
        "voltage under load [V] -> throttle in the units above. Inputs are clamped to the",
        "validity box (a request below the box gets the box's lowest throttle, not zero: stop",
        "the motors by disarming, not through this map) and the output to the encoding range.",
        "Allocation-free; define THRUSTMAP_USE_FLOAT before including for float32 arithmetic.",
    ]
    out = ["/*\n", comment(lines, " *"), " */\n"]
    out.append("#ifndef THRUSTMAP_GENERATED_H\n#define THRUSTMAP_GENERATED_H\n\n")
    out.append("#include <math.h>\n\n")
    out.append(
        "#ifdef THRUSTMAP_USE_FLOAT\n"
        "#define THRUSTMAP_REAL float\n#define THRUSTMAP_SQRT(x) sqrtf(x)\n"
        "#else\n"
        "#define THRUSTMAP_REAL double\n#define THRUSTMAP_SQRT(x) sqrt(x)\n"
        "#endif\n"
        "#define THRUSTMAP_C(x) ((THRUSTMAP_REAL)(x))\n\n"
    )
    out.append(
        f"#define THRUSTMAP_THRUST_MIN_N {box.thrust_n.lo:.17g}\n"
        f"#define THRUSTMAP_THRUST_MAX_N {box.thrust_n.hi:.17g}\n"
        f"#define THRUSTMAP_VOLTAGE_MIN_V {box.voltage_v.lo:.17g}\n"
        f"#define THRUSTMAP_VOLTAGE_MAX_V {box.voltage_v.hi:.17g}\n"
        f"#define THRUSTMAP_OUT_MIN {scale.lo:.17g} /* {scale.name}, {scale.unit} */\n"
        f"#define THRUSTMAP_OUT_MAX {scale.hi:.17g}\n"
        f"#define THRUSTMAP_VC_V {float(bc):.17g} /* voltage centre (multiple of 1/64 V) */\n"
        f"#define THRUSTMAP_VS_V {float(bs):.17g} /* voltage scale (power of two) */\n"
    )
    out.extend(d + "\n" for d in defines)
    if values is not None:
        out.append(_value_defines(values))
    out.append(
        "\nstatic inline THRUSTMAP_REAL thrustmap_clamp_(THRUSTMAP_REAL x, THRUSTMAP_REAL lo,"
        " THRUSTMAP_REAL hi)\n{\n    return x < lo ? lo : (x > hi ? hi : x);\n}\n\n"
    )
    out.append("static inline float thrustmap_throttle(float thrust_n, float voltage_v)\n{\n")
    out.append(
        "    THRUSTMAP_REAL t = thrustmap_clamp_((THRUSTMAP_REAL)thrust_n,\n"
        "        THRUSTMAP_C(THRUSTMAP_THRUST_MIN_N), THRUSTMAP_C(THRUSTMAP_THRUST_MAX_N));\n"
    )
    if uses_b:
        out.append(
            "    THRUSTMAP_REAL b = thrustmap_clamp_((THRUSTMAP_REAL)voltage_v,\n"
            "        THRUSTMAP_C(THRUSTMAP_VOLTAGE_MIN_V), THRUSTMAP_C(THRUSTMAP_VOLTAGE_MAX_V));\n"
            "    THRUSTMAP_REAL v = (b - THRUSTMAP_C(THRUSTMAP_VC_V))"
            " * THRUSTMAP_C(1.0 / THRUSTMAP_VS_V);\n"
            "    (void)v;\n"
        )
    else:
        out.append("    (void)voltage_v;\n")
    if tmap.correction is not None:
        g = tmap.correction
        graw = {(0, j): Fraction(c) for j, c in enumerate(g.coefficients)}
        h = _recentre(graw, Fraction(1), bc, bs)
        out.append(
            f"    /* gamma(B), B clamped to {g.voltage_v.lo:g}..{g.voltage_v.hi:g} V, re-centred */\n"
            "    {\n"
            f"        THRUSTMAP_REAL bg = thrustmap_clamp_(b, THRUSTMAP_C({g.voltage_v.lo:.17g}),"
            f" THRUSTMAP_C({g.voltage_v.hi:.17g}));\n"
            "        THRUSTMAP_REAL w = (bg - THRUSTMAP_C(THRUSTMAP_VC_V))"
            " * THRUSTMAP_C(1.0 / THRUSTMAP_VS_V);\n"
            "        THRUSTMAP_REAL gamma = THRUSTMAP_C(0.0);\n"
        )
        for k in sorted((k for _, k in h), reverse=True):
            out.append(f"        gamma = gamma * w + {_lit(h[(0, k)])};\n")
        out.append("        t = gamma * t;\n    }\n")
    out.extend(line + "\n" for line in body)
    out.append(
        "    r = thrustmap_clamp_(r, THRUSTMAP_C(THRUSTMAP_OUT_MIN), THRUSTMAP_C(THRUSTMAP_OUT_MAX));\n"
        "    return (float)r;\n}\n\n#endif /* THRUSTMAP_GENERATED_H */\n"
    )
    return "".join(out)


def _value_defines(values: MapValues) -> str:
    """The map's full-throttle thrust (``fitting.mapvalues``) as C constants, its interval and
    whether it is extrapolated (1: outside the supported region)."""
    full = values.full_throttle
    if full is None:
        return "/* full-throttle thrust: the map cannot say (see the header) */\n"
    hi = full.hi if full.hi is not None and math.isfinite(full.hi) else math.nan
    lo = full.lo if full.lo is not None else math.nan
    return (
        f"#define THRUSTMAP_FULL_THROTTLE_THRUST_N {full.value:.17g} /* at "
        f"{full.voltage_v:.6g} V, per rotor */\n"
        f"#define THRUSTMAP_FULL_THROTTLE_THRUST_LO_N {lo:.17g} /* 95 % interval */\n"
        f"#define THRUSTMAP_FULL_THROTTLE_THRUST_HI_N {hi:.17g}\n"
        f"#define THRUSTMAP_FULL_THROTTLE_EXTRAPOLATED {int(full.extrapolated)}\n"
    ).replace("nan", "NAN")


def export_c_header(tmap: ThrustMap, opts: ExportOptions) -> ExportResult:
    scale = target_scale(opts.encoding or "percent", opts.range_)
    C_HEADER.require({"range_lo": scale.lo, "range_hi": scale.hi})
    mv = export_values(tmap, scale, opts, reference_voltage(tmap, opts.voltage_v))
    return ExportResult(
        target="c-header",
        text=c_header_text(tmap, scale, mv),
        values={"scale": scale, "map_values": mv}
        | ({} if mv.full_throttle is None else {"full_throttle_thrust_n": mv.full_throttle.value}),
        suffix=".h",
    )
