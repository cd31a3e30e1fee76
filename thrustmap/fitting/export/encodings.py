"""Exports: a thrust map in each throttle encoding, and parameters firmware can load.

A map gives throttle in percent of its native scale, Th% = f(T, B) (with a γ block,
f(γ(B)·T, B)). Every throttle encoding is affine in percent, native = lo + pct/100·(hi − lo),
and every model here is linear in its coefficients, so rescaling is exact: multiply each
coefficient by (hi − lo)/100 and add lo to the constant term (the LA model has no constant term,
so it keeps an explicit offset). ``EncodedMap.evaluate`` equals ``scale.from_pct(map.throttle_pct)``
to rounding (about 1e-15 relative).

Firmware exports (``export_firmware``) fit each firmware's own curve to samples of the map over
its validity box and report the residual of that curve form; the C header (``export_c``) carries
the exact map. Every export text starts with a comment header naming the map (file sha256), its
validity box and the residual of the exported form.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from thrustmap.core.errors import ConfigError
from thrustmap.core.units import SCALES, ThrottleScale, range_problem
from thrustmap.core.version import package_version
from thrustmap.fitting.mapfile import GammaCorrection, ThrustMap
from thrustmap.fitting.mapvalues import MapValue, MapValues, map_values, pct_to_native
from thrustmap.fitting.models import PolyModel

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]

#: Standard gravity, for kg -> N and N -> gram-force.
G0_MPS2 = 9.80665


# -- encodings ----------------------------------------------------------------------------------
def target_scale(encoding: str, range_: tuple[float, float] | None = None) -> ThrottleScale:
    """The named encoding with optional endpoints LO:HI (in that encoding's units)."""
    try:
        base = SCALES[encoding]
    except KeyError:
        raise ConfigError(
            f"unknown encoding '{encoding}'; expected one of: {', '.join(SCALES)}"
        ) from None
    if range_ is None:
        return base
    lo, hi = range_
    if not lo < hi:
        raise ConfigError(f"--range: expected LO < HI, got {lo:g}:{hi:g}")
    if (why := range_problem(encoding, lo, hi)) is not None:
        raise ConfigError(f"--range {why}")
    return base.with_range(lo, hi)


@dataclass(frozen=True)
class EncodedMap:
    """A map whose output is in a target encoding: native = offset + Σ coefficients_k·φ_k(T', B).

    T' = γ(B)·T when ``correction`` is present (the same γ block as the source map; γ is
    dimensionless, so it does not change with the encoding).
    """

    model: str
    scale: ThrottleScale
    offset: float
    coefficients: tuple[float, ...]
    correction: GammaCorrection | None = None

    def evaluate(
        self, thrust_n: npt.ArrayLike, voltage_v: npt.ArrayLike, *, corrected: bool = True
    ) -> FloatArray:
        from thrustmap.fitting.models import get_model

        t = np.asarray(thrust_n, float)
        if corrected and self.correction is not None:
            t = self.correction.gamma(voltage_v) * t
        core = get_model(self.model).evaluate(self.coefficients, t, voltage_v)
        return np.asarray(self.offset + core, dtype=float)


def _constant_index(tmap_model: str) -> int | None:
    from thrustmap.fitting.models import get_model

    names = get_model(tmap_model).term_names
    return names.index("1") if "1" in names else None


def rescale(tmap: ThrustMap, scale: ThrottleScale) -> EncodedMap:
    """Exact affine rescaling of ``tmap`` (percent) into ``scale`` (its native units)."""
    gain = scale.span / 100.0
    coefs = [gain * c for c in tmap.coefficients]
    offset = scale.lo
    k0 = _constant_index(tmap.model)
    if k0 is not None:
        coefs[k0] += offset
        offset = 0.0
    return EncodedMap(tmap.model, scale, offset, tuple(coefs), tmap.correction)


def to_percent(encoded: EncodedMap) -> tuple[float, ...]:
    """Inverse of ``rescale``: the percent-of-scale coefficients back from an encoded map."""
    gain = encoded.scale.span / 100.0
    coefs = list(encoded.coefficients)
    k0 = _constant_index(encoded.model)
    if k0 is not None:
        coefs[k0] -= encoded.scale.lo
    elif abs(encoded.offset - encoded.scale.lo) > 1e-12 * max(1.0, abs(encoded.scale.lo)):
        raise ConfigError("encoded map offset does not match its scale's low end")
    return tuple(c / gain for c in coefs)


# -- shared pieces for every export ------------------------------------------------------------
@dataclass(frozen=True)
class Samples:
    """Points (T per rotor [N], B [V], throttle [% of the map's native scale])."""

    thrust_n: FloatArray
    voltage_v: FloatArray
    throttle_pct: FloatArray


def map_samples(
    tmap: ThrustMap, *, n_thrust: int = 41, n_voltage: int = 9, voltage_v: float | None = None
) -> Samples:
    """A grid over the validity box (or one voltage), throttle from the map (γ applied)."""
    box = tmap.validity
    t = np.linspace(box.thrust_n.lo, box.thrust_n.hi, n_thrust)
    if voltage_v is not None:
        b = np.array([float(voltage_v)])
    elif box.voltage_v.hi > box.voltage_v.lo:
        b = np.linspace(box.voltage_v.lo, box.voltage_v.hi, n_voltage)
    else:
        b = np.array([box.voltage_v.lo])
    tt, bb = np.meshgrid(t, b)
    tf, bf = tt.ravel(), bb.ravel()
    return Samples(tf, bf, np.asarray(tmap.throttle_pct(tf, bf), dtype=float))


def reference_voltage(tmap: ThrustMap, voltage_v: float | None) -> float:
    """The voltage a voltage-free firmware curve is fitted at (default: top of the box)."""
    box = tmap.validity.voltage_v
    if voltage_v is None:
        return box.hi
    if not box.lo - 1e-9 <= voltage_v <= box.hi + 1e-9:
        raise ConfigError(
            f"--voltage-v {voltage_v:g} V is outside the map's voltage box "
            f"{box.lo:g}..{box.hi:g} V; the map says nothing there"
        )
    return float(voltage_v)


def require_voltage(tmap: ThrustMap, target: str) -> None:
    """Voltage-compensated exports need a map that varies with voltage over a real range."""
    box = tmap.validity.voltage_v
    if not tmap.model_def.uses_voltage:
        raise ConfigError(
            f"{target} export fits voltage compensation, but map model '{tmap.model}' has no "
            "voltage term; refit with a voltage model (e.g. motor or poly2)"
        )
    if not box.hi > box.lo:
        raise ConfigError(
            f"{target} export fits voltage compensation, but the map was fitted at one voltage "
            f"({box.lo:g} V); record a sweep over a battery discharge"
        )


def rms_max(err: npt.ArrayLike) -> tuple[float, float]:
    e = np.asarray(err, float)
    return float(np.sqrt(np.mean(e**2))), float(np.max(np.abs(e)))


def header_lines(
    tmap: ThrustMap,
    title: str,
    residual: Sequence[str],
    values: MapValues | None = None,
    outside: Sequence[str] = (),
) -> list[str]:
    """Comment header lines (without the comment marker) every export starts with: the map,
    its box, the residual of the exported form, the map's values this export writes (computed
    once, ``fitting.mapvalues``) and every written value outside the supported region
    (``values``' extrapolated ones and the export's own ``outside`` lines), with its interval."""
    box = tmap.validity
    digest = tmap.file_sha256 or "(map built in memory; no file hash)"
    lines = [
        f"thrustmap {package_version()} export: {title}",
        f"map file sha256: {digest}",
        f"map model: {tmap.model} ({tmap.model_def.formula}), loss {tmap.loss}, "
        f"strategy {tmap.strategy}, created {tmap.created_utc or 'unknown'}",
        f"map native throttle scale: {tmap.throttle_scale.name} "
        f"{tmap.throttle_scale.lo:g}..{tmap.throttle_scale.hi:g} {tmap.throttle_scale.unit}",
        f"validity box: thrust {box.thrust_n.lo:.6g}..{box.thrust_n.hi:.6g} N per rotor, "
        f"voltage {box.voltage_v.lo:.6g}..{box.voltage_v.hi:.6g} V, "
        f"throttle {box.throttle_pct.lo:.6g}..{box.throttle_pct.hi:.6g} %",
    ]
    if tmap.correction is not None:
        g = tmap.correction
        lines.append(
            "gamma correction: gamma(B) = "
            + " + ".join(f"{c:.10g}*B^{k}" for k, c in enumerate(g.coefficients))
            + f", B clamped to {g.voltage_v.lo:g}..{g.voltage_v.hi:g} V"
        )
    lines.extend(f"residual: {r}" for r in residual)
    if values is not None:
        lines += value_lines(tmap, values, outside)
    return lines


def value_lines(tmap: ThrustMap, values: MapValues, outside: Sequence[str] = ()) -> list[str]:
    """The map's values (one computation for every export, the report and predict) and the
    list of written values outside the supported region, each with its interval."""
    native = pct_to_native(tmap)
    unit = tmap.throttle_scale.unit

    def shown(v: MapValue) -> str:
        if v.unit != "%":
            return v.line()
        lo, hi = (None, None) if v.lo is None or v.hi is None else (native(v.lo), native(v.hi))
        extra = "" if lo is None else f" ({lo:.6g}..{hi:.6g} {unit})"
        return f"{v.line()}; = {native(v.value):.6g} {unit}{extra}"

    lines = ["map values (computed once from the map: the same in every export, the report "
             "and `thrustmap predict`):"]  # fmt: skip
    lines += [f"  {shown(v)}" for v in values.all()]
    lines += [f"  {why}" for why in values.unknown]
    out = [f"  {v.name}: {v.value:.4g} {v.unit}, {v.interval_text()}" for v in values.outside()]
    out += [f"  {line}" for line in outside]
    lines.append("written values outside the supported region (extrapolated):" if out else
                 "written values outside the supported region: none")  # fmt: skip
    return lines + out


def comment(lines: Sequence[str], marker: str) -> str:
    return "".join(f"{marker} {line}".rstrip() + "\n" for line in lines)


@dataclass(frozen=True)
class ExportResult:
    """The text of an export plus the numbers it reports (for tests and the CLI summary)."""

    target: str
    text: str
    values: dict[str, Any] = field(default_factory=dict)
    residual: dict[str, float] = field(default_factory=dict)
    suffix: str = ".txt"


@dataclass(frozen=True)
class ExportOptions:
    range_: tuple[float, float] | None = None
    encoding: str | None = None
    mass_kg: float | None = None
    rotors: int | None = None
    voltage_v: float | None = None
    firmware: str | None = None
    spin_max: float = 0.95
    c_real: str = "double"


def hover_thrust_n(opts: ExportOptions) -> float | None:
    """Thrust per rotor to hover, N (None without --mass-kg)."""
    if opts.mass_kg is None:
        return None
    return opts.mass_kg * G0_MPS2 / (opts.rotors or 4)


def export_values(
    tmap: ThrustMap, scale: ThrottleScale, opts: ExportOptions, voltage_v: float
) -> MapValues:
    """The map's values an export writes (``fitting.mapvalues``): the full-throttle thrust at
    the top of ``scale`` (the export's output range), the hover throttle with --mass-kg, the
    spin-up, at ``voltage_v``: one computation, the same numbers in every export."""
    full_pct = float(SCALES[scale.name].to_pct(scale.hi))
    return map_values(tmap, voltage_v, full_pct=full_pct, hover_thrust_n=hover_thrust_n(opts))


def is_poly(tmap: ThrustMap) -> bool:
    return isinstance(tmap.model_def, PolyModel)
