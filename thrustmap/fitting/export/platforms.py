"""Framework and research-platform exports: Aerostack2's polynomial map and seed 2's Crazyflie
linearisation. Same conventions as ``export_firmware``: fitted to samples of the map over its
validity box, with the residual of the exported form in the comment header.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from thrustmap.core.errors import FitError
from thrustmap.core.units import ThrottleScale
from thrustmap.fitting.export.encodings import (
    G0_MPS2,
    ExportOptions,
    ExportResult,
    comment,
    export_values,
    header_lines,
    map_samples,
    reference_voltage,
    rescale,
    rms_max,
    target_scale,
)
from thrustmap.fitting.export.rules import AEROSTACK2
from thrustmap.fitting.mapfile import ThrustMap
from thrustmap.fitting.models import MODELS, PolyModel

FloatArray = npt.NDArray[np.float64]


# =============================================================================================
# Crazyflie (seed 2)
# =============================================================================================
@dataclass(frozen=True)
class CrazyflieSeed2:
    a: float
    b: float
    c: float
    f_max_g: float
    rotors: int
    residual_lines: list[str]
    text: str


def fit_quadratic(
    u: npt.ArrayLike, thrust_g: npt.ArrayLike, through: tuple[float, float] | None = None
) -> tuple[float, float, float]:
    """Seed 2 eq. 2 by least squares (solved centred and scaled, expanded exactly); with
    ``through`` = (u_top, f_top) the polynomial passes exactly through that point (the map's
    full-throttle thrust at the top of the command range)."""
    x = np.asarray(u, float)
    y = np.asarray(thrust_g, float)
    if x.size < 3:
        raise FitError("the Crazyflie thrust polynomial needs at least three points")
    if through is not None:
        return _fit_quadratic_through(x, y, *through)
    xc, xs = float(np.mean(x)), float(np.std(x)) or 1.0
    z = (x - xc) / xs
    (p2, p1, p0), *_ = np.linalg.lstsq(np.stack([z * z, z, np.ones_like(z)], axis=1), y, rcond=None)
    a = p2 / xs**2
    b = p1 / xs - 2 * p2 * xc / xs**2
    c = p0 - p1 * xc / xs + p2 * xc**2 / xs**2
    return float(a), float(b), float(c)


def _fit_quadratic_through(
    x: FloatArray, y: FloatArray, u_top: float, f_top: float
) -> tuple[float, float, float]:
    """a·u² + b·u + c with a·u_top² + b·u_top + c = f_top: least squares in (a, b) on
    y − f_top = a·(u² − u_top²) + b·(u − u_top), scaled by u_top for conditioning."""
    s = abs(u_top) or 1.0
    z, zt = x / s, u_top / s
    cols = np.stack([z * z - zt * zt, z - zt], axis=1)
    (p2, p1), *_ = np.linalg.lstsq(cols, y - f_top, rcond=None)
    a, b = p2 / s**2, p1 / s
    return float(a), float(b), float(f_top - a * u_top**2 - b * u_top)


def crazyflie_seed2(
    tmap: ThrustMap, scale: ThrottleScale, opts: ExportOptions, full_thrust_n: float | None
) -> CrazyflieSeed2:
    """Seed 2's polynomial at the reference voltage, through the map's full-throttle thrust
    (``full_thrust_n`` per rotor, ``fitting.mapvalues``) at the top of the command range."""
    rotors = opts.rotors or 4
    b_ref = reference_voltage(tmap, opts.voltage_v)
    ref = map_samples(tmap, voltage_v=b_ref, n_thrust=81)
    u = scale.from_pct(ref.throttle_pct)
    to_g = 1000.0 / G0_MPS2 * rotors
    top = None if full_thrust_n is None else (scale.hi, full_thrust_n * to_g)
    a, b, c = fit_quadratic(u, ref.thrust_n * to_g, through=top)
    f_max = a * scale.hi**2 + b * scale.hi + c
    r_ref = rms_max(a * u * u + b * u + c - ref.thrust_n * to_g)
    box = map_samples(tmap)
    ub = scale.from_pct(box.throttle_pct)
    r_box = rms_max(a * ub * ub + b * ub + c - box.thrust_n * to_g)
    lines = [
        f"seed 2 thrust polynomial vs map at {b_ref:g} V: RMS {r_ref[0]:.3f} g, max "
        f"{r_ref[1]:.3f} g of collective thrust ({rotors} rotors)",
        f"over the voltage box (the polynomial has no voltage term): RMS {r_box[0]:.3f} g, "
        f"max {r_box[1]:.3f} g",
    ]
    text = (
        "seed2_linearisation:\n"
        '  forward: "thrust_g = a*u^2 + b*u + c   (collective thrust in gram-force, u the raw '
        f'command on {scale.lo:g}..{scale.hi:g})"\n'
        '  linearise: "u\' = (a*u^2 + b*u + c) / f_max_g * 65536"\n'
        f"  a: {a!r}\n  b: {b!r}\n  c: {c!r}\n"
        f"  f_max_g: {f_max!r}   # the polynomial at u = {scale.hi:g}\n"
        f"  rotors: {rotors}\n  voltage_v: {b_ref!r}\n"
        f'  thrust_n_per_rotor: "T = (a*u^2 + b*u + c) * {G0_MPS2 / 1000 / rotors!r}"\n'
    )
    return CrazyflieSeed2(a, b, c, f_max, rotors, lines, text)


def crazyflie_linearise(u: npt.ArrayLike, cf: CrazyflieSeed2) -> FloatArray:
    """Seed 2 eq. 2-3: u' = û/f_max·65536, û = a·u² + b·u + c (clamped to 0..65535)."""
    x = np.asarray(u, float)
    uhat = cf.a * x * x + cf.b * x + cf.c
    return np.asarray(np.clip(uhat / cf.f_max_g * 65536.0, 0.0, 65535.0), dtype=float)


# =============================================================================================
# Aerostack2 (as2_core PolynomialThrustMap, used by as2_platform_betaflight)
# =============================================================================================
_AS2_POWERS = ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2))  # a b c d e f


def export_aerostack2(tmap: ThrustMap, opts: ExportOptions) -> ExportResult:
    """ROS 2 parameters for as2_core's PolynomialThrustMap (names read from aerostack2 source).

    throttle = a + b·T + c·V + d·T² + e·T·V + f·V² in the platform's throttle units
    (min_throttle..max_throttle, µs for as2_platform_betaflight), T the collective thrust
    divided by the motor count, γ(V) = gamma2·V² + gamma1·V + gamma0 multiplying T.
    """
    scale = target_scale(opts.encoding or "pwm", opts.range_)
    rotors = opts.rotors or 4
    model = tmap.model_def
    enc = rescale(tmap, scale)
    coef: dict[tuple[int, int], float] = {}
    exact = isinstance(model, PolyModel) and set(model.powers) <= set(_AS2_POWERS)
    if exact:
        assert isinstance(model, PolyModel)
        coef = dict(zip(model.powers, enc.coefficients, strict=True))
    else:  # refit the as2 form to the map over its box, in output units
        s = map_samples(tmap, n_thrust=61, n_voltage=15)
        t_in = s.thrust_n
        if tmap.correction is not None:
            t_in = tmap.correction.gamma(s.voltage_v) * s.thrust_n
        y = enc.evaluate(t_in, s.voltage_v, corrected=False)
        full = MODELS["poly2"]
        c = full.fit(t_in, s.voltage_v, y, "l2") if model.uses_voltage else None
        if c is None:
            (a1, b1, d1), *_ = np.linalg.lstsq(
                np.stack([np.ones_like(t_in), t_in, t_in**2], axis=1), y, rcond=None
            )
            coef = {(0, 0): float(a1), (1, 0): float(b1), (2, 0): float(d1)}
        else:
            assert isinstance(full, PolyModel)
            coef = dict(zip(full.powers, (float(x) for x in c), strict=True))
    ab = [coef.get(p, 0.0) for p in _AS2_POWERS]
    gamma = (0.0, 0.0, 0.0)
    g_exact = True
    if tmap.correction is not None:
        g = tmap.correction
        gc = list(g.coefficients)
        if len(gc) > 3:
            vv = np.linspace(g.voltage_v.lo, g.voltage_v.hi, 50)
            gc = list(np.polynomial.polynomial.polyfit(vv, g.gamma(vv), 2))
            g_exact = False
        gc += [0.0] * (3 - len(gc))
        gamma = (float(gc[2]), float(gc[1]), float(gc[0]))
    # residual of the as2 form (without as2's uint16 truncation) against the map
    s = map_samples(tmap)
    t_eff = s.thrust_n
    if tmap.correction is not None:
        t_eff = (gamma[0] * s.voltage_v**2 + gamma[1] * s.voltage_v + gamma[2]) * s.thrust_n
    pred = sum(k * t_eff**i * s.voltage_v**j for k, (i, j) in zip(ab, _AS2_POWERS, strict=True))
    err = 100 * (np.asarray(pred) - scale.from_pct(s.throttle_pct)) / scale.span
    r = rms_max(err)
    how = (
        "exact coefficients (map is a 2nd-degree surface)"
        if exact
        else f"2nd-degree surface refitted to the {tmap.model} map over its box"
    )
    why = ""
    if exact and tmap.correction is not None and r[1] > 1e-9:
        why = " (only where the map clamps gamma's voltage range and as2 does not)"
    residual = [
        f"{how}: RMS {r[0]:.3g} %, max {r[1]:.3g} % of the {scale.lo:g}..{scale.hi:g} range"
        + why
        + ("" if g_exact else "; gamma refitted to degree 2"),
    ]
    notes = [
        "parameter names from aerostack2 as2_core PolynomialThrustMap (polynomial_thrust_map.*)"
        " as loaded by as2_platform_betaflight; T = collective thrust / motors",
        "as2 truncates the result to whole microseconds and clamps it to min..max_throttle; "
        "it does not clamp the voltage fed to gamma (this tool's gamma is clamped to its range)",
    ]
    if rotors != 4:
        notes.append(
            f"WARNING: as2_platform_betaflight hard-codes 4 motors; this export uses {rotors}"
        )
    box = tmap.validity.thrust_n
    written = {
        "min_throttle": scale.lo, "max_throttle": scale.hi,
        "thrust_min_n": rotors * box.lo, "thrust_max_n": rotors * box.hi,
    }  # fmt: skip
    AEROSTACK2.require(written)
    notes.append(f"firmware: {AEROSTACK2.header()}")
    notes += [f"writes {line}" for line in AEROSTACK2.changes(written)]
    mv = export_values(tmap, scale, opts, reference_voltage(tmap, opts.voltage_v))
    title = "Aerostack2 platform parameters (ROS 2 YAML)"
    lines = header_lines(tmap, title, residual, mv) + notes
    doc = comment(lines, "#") + "/**:\n  ros__parameters:\n    use_thrust_map: true\n"
    doc += f"    thrust:\n      max: {rotors * box.hi!r}  # N, collective\n"
    doc += f"      min: {rotors * box.lo!r}  # N, collective\n"
    doc += "    polynomial_thrust_map:\n"
    doc += f"      max_throttle: {scale.hi!r}\n      min_throttle: {scale.lo!r}\n"
    doc += "      # throttle = a + b*T + c*V + d*T^2 + e*T*V + f*V^2 (T per motor, N; V volts)\n"
    for name, v in zip("abcdef", ab, strict=True):
        doc += f"      {name}: {v!r}\n"
    doc += f"      use_correction_factor: {'true' if tmap.correction is not None else 'false'}\n"
    doc += "      # gamma(V) = gamma2*V^2 + gamma1*V + gamma0\n"
    for name, v in zip(("gamma2", "gamma1", "gamma0"), gamma, strict=True):
        doc += f"      {name}: {v!r}\n"
    values: dict[str, Any] = dict(zip("abcdef", ab, strict=True))
    if mv.full_throttle is not None:
        values["full_throttle_thrust_n"] = mv.full_throttle.value
    values["map_values"] = mv
    values.update(dict(zip(("gamma2", "gamma1", "gamma0"), gamma, strict=True)))
    return ExportResult("aerostack2", doc, values, {"rms_pct": r[0], "max_pct": r[1]}, ".yaml")
