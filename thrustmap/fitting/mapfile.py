"""The thrust-map file: a versioned JSON document and the object that evaluates it.

Directions (thrust is per rotor, N; voltage is the battery terminal voltage, V):
- inverse (the map proper, the seed paper's Th = f(T, B)): ``throttle_pct`` / ``throttle_native``
- forward (seed 2's direction, thrust from command): ``thrust_n``
With a γ(B) correction block, the inverse applies Th = f̂(γ(B)·T_c, B) (seed paper eq. 9) and the
forward gives T_c = T/γ(B); pass ``corrected=False`` for the bench map alone.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from thrustmap.core.errors import ConfigError, DataFormatError, FitError
from thrustmap.core.files import atomic_write_text
from thrustmap.core.jsonfile import Fields, load_json
from thrustmap.core.physical import (
    flight_against_map_pack,
    gamma_outside_band,
    hover_outside_map,
)
from thrustmap.core.units import ThrottleScale
from thrustmap.core.version import package_version
from thrustmap.fitting.interval import Interval, Region, Standing, interval_range
from thrustmap.fitting.models import Model, get_model, motor_forward

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
MAP_FORMAT = "thrustmap.map"
MAP_VERSION = 1
STRATEGIES = ("LA", "SR", "MR", "unknown")


@dataclass(frozen=True)
class Box:
    """A closed interval [lo, hi]."""

    lo: float
    hi: float

    def contains(self, x: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        a = np.asarray(x, float)
        return np.asarray((a >= self.lo) & (a <= self.hi))

    def to_list(self) -> list[float]:
        return [self.lo, self.hi]


@dataclass(frozen=True)
class ValidityBox:
    """Where the map was fitted: thrust per rotor, voltage, and throttle (percent)."""

    thrust_n: Box
    voltage_v: Box
    throttle_pct: Box

    def contains(self, thrust_n: npt.ArrayLike, voltage_v: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        return np.asarray(self.thrust_n.contains(thrust_n) & self.voltage_v.contains(voltage_v))

    def to_dict(self) -> dict[str, list[float]]:
        return {
            "thrust_n": self.thrust_n.to_list(),
            "voltage_v": self.voltage_v.to_list(),
            "throttle_pct": self.throttle_pct.to_list(),
        }


def gamma_text(coefficients: Sequence[float], digits: int = 6) -> str:
    """γ(B) as a person writes it: ``1.3374 − 0.0277582·B`` (never ``+ -``)."""
    text = ""
    for k, c in enumerate(coefficients):
        term = f"{abs(c):.{digits}g}" + ("" if k == 0 else "·B" if k == 1 else f"·B^{k}")
        if k == 0:
            text = f"{c:.{digits}g}"
        else:
            text += f" {'−' if c < 0 else '+'} {term}"
    return text


@dataclass(frozen=True)
class GammaCorrection:
    """γ(B) = Σ coefficients[k]·B^k (ascending powers), fitted on flight data (eq. 11)."""

    coefficients: tuple[float, ...]
    voltage_v: Box
    loss: str = "l2"
    metrics: dict[str, Any] = field(default_factory=dict)
    sources: tuple[dict[str, Any], ...] = ()

    def gamma(self, voltage_v: npt.ArrayLike) -> FloatArray:
        b = np.asarray(voltage_v, float)
        # Clamp to the flown voltage range: a polynomial extrapolated past it is not evidence.
        b = np.clip(b, self.voltage_v.lo, self.voltage_v.hi)
        return np.asarray(np.polynomial.polynomial.polyval(b, self.coefficients), dtype=float)

    def to_dict(self) -> dict[str, Any]:
        return {
            "formula": "gamma = "
            + " + ".join(
                f"g{k}" + ("" if k == 0 else "*B" if k == 1 else f"*B^{k}")
                for k in range(len(self.coefficients))
            ),
            "coefficients": list(self.coefficients),
            "voltage_v": self.voltage_v.to_list(),
            "loss": self.loss,
            "metrics": self.metrics,
            "sources": list(self.sources),
        }


@dataclass(frozen=True)
class ThrustMap:
    model: str
    coefficients: tuple[float, ...]
    throttle_scale: ThrottleScale
    validity: ValidityBox
    loss: str = "l2"
    strategy: str = "unknown"
    rotors_on_esc: int | None = None
    thrust_meaning: str = "per_rotor"
    metrics: dict[str, Any] = field(default_factory=dict)
    selection: dict[str, Any] = field(default_factory=dict)
    sources: tuple[dict[str, Any], ...] = ()
    correction: GammaCorrection | None = None
    #: how the coefficients were identified (which were set by physics, and why)
    identification: dict[str, Any] = field(default_factory=dict)
    #: prediction interval learned from held-out residuals (see fitting.interval)
    interval: dict[str, Any] = field(default_factory=dict)
    #: lowest reliably spinning command measured on the stand (see fitting.spinup)
    spin_up: dict[str, Any] = field(default_factory=dict)
    #: the command above which the ESC's output saturated on the stand (selection.top; empty:
    #: thrust rose to the top command); the full-throttle thrust is the map's thrust there
    saturation: dict[str, Any] = field(default_factory=dict)
    #: where the selected points are in (T, B) (None: a map written before; its box is used)
    supported: Region | None = None
    # read when a map is made, not when this module is imported (importlib.metadata: ~20-60 ms
    # of every command that reads a map, e.g. each fleet worker)
    tool_version: str = field(default_factory=package_version)
    created_utc: str = field(
        default_factory=lambda: datetime.now(timezone.utc).isoformat(timespec="seconds")
    )
    #: sha256 of the file this map was loaded from (empty for a map built in memory)
    file_sha256: str = field(default="", compare=False)

    @property
    def model_def(self) -> Model:
        return get_model(self.model)

    # -- inverse: throttle from thrust -------------------------------------------------------
    def throttle_pct(
        self, thrust_n: npt.ArrayLike, voltage_v: npt.ArrayLike, *, corrected: bool = True
    ) -> FloatArray:
        t = np.asarray(thrust_n, float)
        if corrected and self.correction is not None:
            t = self.correction.gamma(voltage_v) * t
        return self.model_def.evaluate(self.coefficients, t, voltage_v)

    def throttle_native(
        self, thrust_n: npt.ArrayLike, voltage_v: npt.ArrayLike, *, corrected: bool = True
    ) -> FloatArray:
        return self.throttle_scale.from_pct(
            self.throttle_pct(thrust_n, voltage_v, corrected=corrected)
        )

    # -- forward: thrust from throttle --------------------------------------------------------
    def thrust_n(
        self, throttle_pct: npt.ArrayLike, voltage_v: npt.ArrayLike, *, corrected: bool = True
    ) -> FloatArray:
        th, b = np.broadcast_arrays(np.asarray(throttle_pct, float), np.asarray(voltage_v, float))
        if self.model == "motor":
            t = motor_forward(self.coefficients, th, b)
        else:
            t = self._bisect_thrust(th, b)
        if corrected and self.correction is not None:
            t = t / self.correction.gamma(b)
        return np.asarray(t, dtype=float)

    def _bisect_thrust(self, th: FloatArray, b: FloatArray) -> FloatArray:
        """Invert Th = f(T, B) in T by vectorised bisection (maps are monotone in T)."""
        lo = np.zeros_like(th)
        hi = np.full_like(th, max(self.validity.thrust_n.hi, 1e-6) * 3.0)
        f_lo = self.model_def.evaluate(self.coefficients, lo, b)
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            f_mid = self.model_def.evaluate(self.coefficients, mid, b)
            below = f_mid < th
            lo = np.where(below, mid, lo)
            hi = np.where(below, hi, mid)
        t = 0.5 * (lo + hi)
        return np.where(th <= f_lo, 0.0, t)

    def supported_region(self) -> Region:
        """Where the data are (T, B); the validity box for a map written before regions."""
        if self.supported is not None:
            return self.supported
        v = self.validity
        return Region.box(v.thrust_n.lo, v.thrust_n.hi, v.voltage_v.lo, v.voltage_v.hi)

    def prediction_interval(self) -> Interval | None:
        """The map's prediction interval (None for a map without one, e.g. an older file)."""
        if not self.interval:
            return None
        return Interval.from_dict(self.interval, self.supported_region())

    def model_thrust(
        self, thrust_n: npt.ArrayLike, voltage_v: npt.ArrayLike, *, corrected: bool = True
    ) -> FloatArray:
        """The thrust the bench map is evaluated at: γ(B)·T with a correction, else T."""
        t = np.asarray(thrust_n, float)
        if corrected and self.correction is not None:
            t = self.correction.gamma(voltage_v) * t
        return np.asarray(t, dtype=float)

    def interval_parts(
        self,
        thrust_n: npt.ArrayLike,
        voltage_v: npt.ArrayLike,
        *,
        corrected: bool = True,
        within_recording: bool = False,
    ) -> tuple[FloatArray, FloatArray, FloatArray] | None:
        """The prediction interval at (T, B) in parts: (half-width before widening, widening
        factor, distance outside the supported region). None: the map has no interval.
        ``within_recording``: without the second-recording term (``Interval.parts``)."""
        iv = self.prediction_interval()
        if iv is None:
            return None
        t, b = np.broadcast_arrays(
            self.model_thrust(thrust_n, voltage_v, corrected=corrected),
            np.asarray(voltage_v, float),
        )
        design = self.model_def.design(t.ravel(), b.ravel())
        return iv.parts(t, b, design, within_recording=within_recording)

    def standing(self, thrust_n: float, voltage_v: float, *, corrected: bool = True) -> Standing:
        """Where (T, B) stands: inside the supported region, extrapolated within the
        benchmark's evidence, or beyond it; with the interval there (``half_width_pct`` None:
        the map has no interval; its region and the benchmark's limits still answer)."""
        iv = self.prediction_interval()
        region = self.supported_region()
        bare = iv is None
        if iv is None:
            iv = Interval(0.0, 0.0, region.thrust_span_n, region.voltage_unit_v, region, "")
        t = float(self.model_thrust(thrust_n, voltage_v, corrected=corrected))
        design = self.model_def.design(np.array([t]), np.array([float(voltage_v)]))
        st = iv.standing(t, float(voltage_v), design)
        return replace(st, half_width_pct=None) if bare else st

    def interval_pct(
        self,
        thrust_n: npt.ArrayLike,
        voltage_v: npt.ArrayLike,
        *,
        corrected: bool = True,
        within_recording: bool = False,
    ) -> FloatArray | None:
        """Half-width of the map's prediction interval, % throttle: the one interval every
        command and the report use. None: the map has no interval. ``within_recording``:
        without the second-recording term (the adaptive bench's stop rule)."""
        parts = self.interval_parts(
            thrust_n, voltage_v, corrected=corrected, within_recording=within_recording
        )
        if parts is None:
            return None
        return np.asarray(parts[0] * parts[1], dtype=float)

    def interval_over_region(self, *, within_recording: bool = False) -> tuple[float, float] | None:
        """Smallest and largest half-width over the supported region (None: no interval);
        ``within_recording``: without the second-recording term (``Interval.parts``)."""
        iv = self.prediction_interval()
        if iv is None:
            return None
        return interval_range(iv, self.model_def.design, within_recording=within_recording)

    def in_box(self, thrust_n: npt.ArrayLike, voltage_v: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        """Inside the map's supported region (where its data are; the box for older maps)."""
        return self.supported_region().contains(thrust_n, voltage_v)

    def hover_refusal(self, mass_kg: float, rotors: int) -> str | None:
        """Why a vehicle of ``mass_kg`` on ``rotors`` rotors cannot hover on this (bench) map,
        or None: its hover thrust per rotor must lie between the map's thrust at 0 % throttle
        at the lowest voltage and at 100 % at the highest (``core.physical``)."""
        v = self.validity.voltage_v
        lo = float(self.thrust_n(0.0, v.lo, corrected=False))
        hi = float(self.thrust_n(100.0, v.hi, corrected=False))
        return hover_outside_map(mass_kg, rotors, (lo, hi), v.hi)

    def pack_refusal(self, voltage_v: npt.ArrayLike) -> str | None:
        """Why a flight whose battery read ``voltage_v`` cannot have flown this map's motor
        (its cell count, over the middle 90 % of the readings, is not the map's pack:
        ``physical.flight_against_map_pack``), or None. The one check of ``flightlog
        extract``, ``gamma fit`` and ``fleet extract``."""
        v = np.asarray(voltage_v, float)
        v = v[np.isfinite(v)]
        if not v.size:
            return None
        lo, hi = (float(x) for x in np.percentile(v, [5, 95]))
        box = self.validity.voltage_v
        return flight_against_map_pack(lo, hi, box.lo, box.hi)

    def with_correction(self, correction: GammaCorrection | None) -> ThrustMap:
        return replace(self, correction=correction)

    @property
    def bench_sha256(self) -> str:
        """sha256 of what evaluates the bench map (model, coefficients, throttle scale, rotors
        on the ESC): the same for the map with or without a γ correction block, so a Df
        extracted with a map still matches that map once γ is attached."""
        bench = {
            "model": self.model,
            "coefficients": [float(c) for c in self.coefficients],
            "throttle_scale": self.throttle_scale.to_dict(),
            "rotors_on_esc": self.rotors_on_esc,
        }
        return hashlib.sha256(json.dumps(bench, sort_keys=True).encode()).hexdigest()

    # -- file ---------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        m = self.model_def
        return {
            "format": MAP_FORMAT,
            "version": MAP_VERSION,
            "model": self.model,
            "formula": m.formula,
            "terms": list(m.term_names),
            "coefficients": list(self.coefficients),
            "loss": self.loss,
            "units": {
                "thrust": "N per rotor",
                "voltage": "V (battery terminal, under load)",
                "throttle": "% of native scale",
            },
            "throttle_scale": self.throttle_scale.to_dict(),
            "strategy": self.strategy,
            "rotors_on_esc": self.rotors_on_esc,
            "thrust_meaning": self.thrust_meaning,
            "validity": self.validity.to_dict(),
            **(
                {"supported_region": self.supported.to_dict()} if self.supported is not None else {}
            ),
            "metrics": self.metrics,
            "selection": self.selection,
            "sources": list(self.sources),
            "correction": None if self.correction is None else self.correction.to_dict(),
            # written only when present, so maps built without them keep their old bytes
            **({"identification": self.identification} if self.identification else {}),
            **({"interval": self.interval} if self.interval else {}),
            **({"spin_up": self.spin_up} if self.spin_up else {}),
            **({"saturation": self.saturation} if self.saturation else {}),
            "tool_version": self.tool_version,
            "created_utc": self.created_utc,
        }

    def dumps(self) -> str:
        """The map as JSON text. Refuses a map with a number JSON cannot carry (NaN, ±inf),
        naming the field, so a broken fit never reaches a file or a firmware export."""
        doc = self.to_dict()
        bad = _non_finite_path(doc)
        if bad is not None:
            raise FitError(f"map has a non-finite number in field '{bad}'; not written")
        return json.dumps(doc, indent=2, sort_keys=False, allow_nan=False) + "\n"

    def save(self, path: str | Path) -> None:
        atomic_write_text(path, self.dumps())

    @classmethod
    def load(cls, path: str | Path) -> ThrustMap:
        p = Path(path)
        data = load_json(p, what="map file")
        tmap = cls.from_dict(data, source=str(p))
        return replace(tmap, file_sha256=file_sha256(p))

    @classmethod
    def from_dict(cls, data: Any, *, source: str = "<map>") -> ThrustMap:
        """Build a map from its JSON document, checking every number that evaluates it: finite
        coefficients, ordered finite boxes, a finite γ. Errors name the field."""
        if not isinstance(data, dict) or data.get("format") != MAP_FORMAT:
            raise DataFormatError(
                f'not a thrustmap map file (expected "format": "{MAP_FORMAT}")', file=source
            )
        f = Fields(data, source=source)
        version = f.raw("version")
        if version != MAP_VERSION:
            raise DataFormatError(
                f"map file version {version} is not supported (this tool reads {MAP_VERSION})",
                file=source,
            )
        name = f.string("model")
        try:
            model = get_model(name)
        except ConfigError as exc:
            raise f.error(exc.message, "model") from None
        coefs = tuple(f.numbers("coefficients"))
        if len(coefs) != model.n_coefficients:
            raise f.error(
                f"model '{model.name}' needs {model.n_coefficients} coefficients, got {len(coefs)}",
                "coefficients",
            )
        cov = f.sub("interval").obj.get("parameter_covariance") if f.has("interval") else None
        if isinstance(cov, list) and cov and len(cov) != model.n_coefficients:
            raise f.error(
                f"parameter_covariance is {len(cov)}x{len(cov)}; model '{model.name}' has "
                f"{model.n_coefficients} coefficients",
                "interval",
            )
        _check_constraints(f, model, coefs)
        vf = f.sub("validity")
        box = ValidityBox(
            thrust_n=_box(vf, "thrust_n", minimum=0.0),
            voltage_v=_box(vf, "voltage_v", minimum=0.0, positive=True),
            throttle_pct=_box(vf, "throttle_pct"),
        )
        supported = _region(f)
        _check_monotone(f, model, coefs, supported or Region.box(
            box.thrust_n.lo, box.thrust_n.hi, box.voltage_v.lo, box.voltage_v.hi
        ))  # fmt: skip
        correction = None
        if f.has("correction"):
            cf = f.sub("correction")
            gamma = tuple(cf.numbers("coefficients"))
            if not gamma:
                raise cf.error("expected at least one coefficient", "coefficients")
            metrics = cf.obj.get("metrics", {})
            correction = GammaCorrection(
                coefficients=gamma,
                voltage_v=_box(cf, "voltage_v", minimum=0.0, positive=True),
                loss=cf.string("loss", "l2"),
                metrics=dict(metrics) if isinstance(metrics, dict) else {},
                sources=tuple(_list(cf, "sources")),
            )
            flown = np.linspace(correction.voltage_v.lo, correction.voltage_v.hi, 25)
            band = gamma_outside_band(correction.gamma(flown).tolist())
            if band is not None and not correction.metrics.get("forced"):
                raise cf.error(band + " (not written with --force)", "coefficients")
        try:
            throttle_scale = ThrottleScale.from_dict(dict(f.sub("throttle_scale").obj))
        except ConfigError as exc:
            raise f.error(exc.message, "throttle_scale") from None
        if not (
            math.isfinite(throttle_scale.lo)
            and math.isfinite(throttle_scale.hi)
            and throttle_scale.lo != throttle_scale.hi
        ):
            raise f.error("expected finite, different lo and hi", "throttle_scale")
        rotors = data.get("rotors_on_esc")
        if rotors is not None:
            rotors = f.integer("rotors_on_esc", minimum=1, maximum=64)
        return cls(
            model=model.name,
            coefficients=coefs,
            throttle_scale=throttle_scale,
            validity=box,
            loss=f.string("loss", "l2"),
            strategy=f.string("strategy", "unknown"),
            rotors_on_esc=rotors,
            thrust_meaning=f.string("thrust_meaning", "per_rotor"),
            metrics=_dict(f, "metrics"),
            selection=_dict(f, "selection"),
            sources=tuple(_list(f, "sources")),
            correction=correction,
            identification=_dict(f, "identification"),
            interval=_interval(f),
            spin_up=_dict(f, "spin_up"),
            saturation=_saturation(f),
            supported=supported,
            tool_version=f.string("tool_version", ""),
            created_utc=f.string("created_utc", ""),
        )


#: how far (% throttle) a map may fall as thrust rises inside its box before it is refused:
#: a fitted polynomial wiggles by a fraction of a percent; a map that falls by more answers
#: one throttle for two thrusts
MONOTONE_TOLERANCE_PCT = 1.0


def _check_constraints(f: Fields, model: Model, coefs: tuple[float, ...]) -> None:
    """The model's own bounds (``motor``: k0, k1, k2 >= 0, -20 <= c <= 50) hold for every
    coefficient: a hand-edited map that breaks them is refused, naming the coefficient."""
    scale = max([1.0, *(abs(c) for c in coefs)])
    for i, (name, value) in enumerate(zip(model.term_names, coefs, strict=True)):
        lo = model.lower_bounds[i] if model.lower_bounds else -math.inf
        hi = model.upper_bounds[i] if model.upper_bounds else math.inf
        if value < lo - 1e-9 * scale or value > hi + 1e-9 * scale:
            bound = f">= {lo:g}" if value < lo else f"<= {hi:g}"
            raise f.error(
                f"coefficient {i} (term {name}) is {value:g}; model '{model.name}' needs it "
                f"{bound} ({model.formula})",
                "coefficients",
            )


def falls_with_thrust(model: Model, coefs: npt.ArrayLike, region: Region) -> str | None:
    """Where throttle falls as thrust rises inside ``region`` (the map's data: at every
    voltage knot, by more than ``MONOTONE_TOLERANCE_PCT``), or None: then one throttle answers
    one thrust. (Outside the data a polynomial may turn: that is extrapolation, which predict
    already says. ``fit.check_map`` warns at fit time on any fall, however small.)"""
    for b, t_lo, t_hi in zip(region.voltage_v, region.thrust_lo_n, region.thrust_hi_n, strict=True):
        if not t_hi > t_lo:
            continue
        t = np.linspace(t_lo, t_hi, 61)
        th = model.evaluate(coefs, t, np.full_like(t, b))
        if not np.all(np.isfinite(th)):
            return f"the map gives no finite throttle at {b:.2f} V"
        drop = np.maximum.accumulate(th) - th
        k = int(np.argmax(drop))
        if drop[k] > MONOTONE_TOLERANCE_PCT:
            top = int(np.argmax(th[: k + 1]))
            return (
                f"throttle falls by {drop[k]:.2f} % as thrust rises from {t[top]:.3g} to "
                f"{t[k]:.3g} N at {b:.2f} V, inside the map's data: one throttle answers two "
                "thrusts there"
            )
    return None


def _check_monotone(f: Fields, model: Model, coefs: tuple[float, ...], region: Region) -> None:
    """A map whose throttle falls with thrust inside its data (:func:`falls_with_thrust`): a
    model monotone by construction (bounded coefficients, ``motor``) is refused, since only a
    broken file falls; a free polynomial can turn between its points (a fit, not a corrupt
    file): it loads, with a warning."""
    text = falls_with_thrust(model, coefs, region)
    if text is None:
        return
    if model.lower_bounds or "finite" in text:
        raise f.error(text, "coefficients")
    log.warning("%s: model '%s': %s (the motor model cannot)", f.source, model.name, text)


def _box(f: Fields, key: str, *, minimum: float | None = None, positive: bool = False) -> Box:
    lo_hi = f.numbers(key)
    if len(lo_hi) != 2:
        raise f.error(f"expected [lo, hi], got {len(lo_hi)} numbers", key)
    lo, hi = lo_hi
    if lo > hi:
        raise f.error(f"reversed range [{lo:g}, {hi:g}]; expected lo <= hi", key)
    if minimum is not None and lo < minimum:
        raise f.error(f"expected values >= {minimum:g}, got {lo:g}", key)
    if positive and lo <= 0:
        raise f.error(f"expected positive values, got {lo:g}", key)
    return Box(lo, hi)


def _dict(f: Fields, key: str) -> dict[str, Any]:
    if not f.has(key):
        return {}
    value = f.raw(key)
    if not isinstance(value, dict):
        raise f.error("expected an object", key)
    return dict(value)


def _saturation(f: Fields) -> dict[str, Any]:
    """The ``saturation`` block: its command a number in 0..100 % of the scale."""
    block = _dict(f, "saturation")
    pct = block.get("throttle_pct")
    if block and not (
        isinstance(pct, (int, float)) and not isinstance(pct, bool) and 0.0 < pct <= 100.0
    ):
        raise f.error(f"throttle_pct {pct!r}: expected a number in 0..100 (% of the scale)",
                      "saturation")  # fmt: skip
    return block


def _list(f: Fields, key: str) -> list[Any]:
    if not f.has(key):
        return []
    value = f.raw(key)
    if not isinstance(value, list):
        raise f.error("expected a list", key)
    return value


def _interval(f: Fields) -> dict[str, Any]:
    """The prediction-interval block: its numbers are used by predict, so they are checked."""
    if not f.has("interval") or not f.raw("interval"):
        return {}
    sub = f.sub("interval")
    out = dict(sub.obj)
    for key in ("half_width_pct", "growth_per_span"):
        out[key] = sub.number(key, minimum=0.0)
    if sub.has("growth_per_reach"):
        out["growth_per_reach"] = sub.number("growth_per_reach", minimum=0.0)
    if sub.has("evidence_limit"):
        lim = sub.sub("evidence_limit")
        out["evidence_limit"] = {
            **lim.obj,
            "thrust_reach_ratio": lim.number("thrust_reach_ratio", minimum=1.0),
            "voltage_log_distance": lim.number("voltage_log_distance", minimum=0.0),
        }
    if sub.has("z"):
        out["z"] = sub.number("z", minimum=0.0)
    cov = sub.obj.get("parameter_covariance") or []
    if not isinstance(cov, list) or not all(
        isinstance(row, list)
        and len(row) == len(cov)
        and all(isinstance(x, (int, float)) and math.isfinite(x) for x in row)
        for row in cov
    ):
        raise sub.error("expected a square matrix of finite numbers", "parameter_covariance")
    return out


def _region(f: Fields) -> Region | None:
    """The supported region: knots ascending in voltage, thrust ranges ordered, all finite."""
    if not f.has("supported_region") or not f.raw("supported_region"):
        return None
    sub = f.sub("supported_region")
    knots = sub.numbers("voltage_v")
    lo = sub.numbers("thrust_lo_n")
    hi = sub.numbers("thrust_hi_n")
    if not knots or len(lo) != len(knots) or len(hi) != len(knots):
        raise sub.error("expected voltage_v, thrust_lo_n, thrust_hi_n of one length", "voltage_v")
    if any(b <= 0 for b in knots) or any(k2 < k1 for k1, k2 in zip(knots, knots[1:], strict=False)):
        raise sub.error("expected positive voltages in ascending order", "voltage_v")
    if any(a < 0 or a > b for a, b in zip(lo, hi, strict=True)):
        raise sub.error("expected 0 <= thrust_lo_n <= thrust_hi_n at every knot", "thrust_lo_n")
    b_lo = sub.number("voltage_lo_v", minimum=0.0)
    b_hi = sub.number("voltage_hi_v", minimum=b_lo)
    return Region(tuple(knots), tuple(lo), tuple(hi), b_lo, b_hi)


def _non_finite_path(obj: Any, path: str = "") -> str | None:
    """The path of the first NaN/±inf inside a JSON-ready structure, or None."""
    if isinstance(obj, float):
        return None if math.isfinite(obj) else (path or "<value>")
    if isinstance(obj, dict):
        for k, v in obj.items():
            found = _non_finite_path(v, f"{path}.{k}" if path else str(k))
            if found is not None:
                return found
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            found = _non_finite_path(v, f"{path}[{i}]")
            if found is not None:
                return found
    return None


def json_ready(obj: Any) -> Any:
    """A copy of a JSON-ready structure with every NaN/±inf replaced by None (null)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: json_ready(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_ready(v) for v in obj]
    if isinstance(obj, np.generic):
        return json_ready(obj.item())
    return obj


def file_sha256(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()
