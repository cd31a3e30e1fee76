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
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from thrustmap import __version__
from thrustmap.errors import DataFormatError
from thrustmap.fitting.models import Model, get_model, motor_forward
from thrustmap.jsonfile import loads_json
from thrustmap.units import ThrottleScale

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
    tool_version: str = __version__
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

    def in_box(self, thrust_n: npt.ArrayLike, voltage_v: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        return self.validity.contains(thrust_n, voltage_v)

    def with_correction(self, correction: GammaCorrection | None) -> ThrustMap:
        return replace(self, correction=correction)

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
            "metrics": self.metrics,
            "selection": self.selection,
            "sources": list(self.sources),
            "correction": None if self.correction is None else self.correction.to_dict(),
            "tool_version": self.tool_version,
            "created_utc": self.created_utc,
        }

    def dumps(self) -> str:
        return json.dumps(self.to_dict(), indent=2, sort_keys=False) + "\n"

    def save(self, path: str | Path) -> None:
        Path(path).write_text(self.dumps(), encoding="utf-8")

    @classmethod
    def load(cls, path: str | Path) -> ThrustMap:
        p = Path(path)
        try:
            raw = p.read_bytes()
        except OSError as exc:
            raise DataFormatError(f"cannot read map file: {exc.strerror}", file=str(p)) from None
        try:
            data = loads_json(raw.decode("utf-8"), source=str(p))  # bounded depth, strict numbers
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            line = getattr(exc, "lineno", None)
            raise DataFormatError(f"not a JSON map file ({exc})", file=str(p), line=line) from None
        tmap = cls.from_dict(data, source=str(p))
        return replace(tmap, file_sha256=hashlib.sha256(raw).hexdigest())

    @classmethod
    def from_dict(cls, data: Any, *, source: str = "<map>") -> ThrustMap:
        def need(obj: Any, key: str, where: str = "") -> Any:
            if not isinstance(obj, dict) or key not in obj:
                raise DataFormatError(f"map file has no field '{where}{key}'", file=source)
            return obj[key]

        if not isinstance(data, dict) or data.get("format") != MAP_FORMAT:
            raise DataFormatError(
                f'not a thrustmap map file (expected "format": "{MAP_FORMAT}")', file=source
            )
        version = need(data, "version")
        if version != MAP_VERSION:
            raise DataFormatError(
                f"map file version {version} is not supported (this tool reads {MAP_VERSION})",
                file=source,
            )
        try:
            model = get_model(str(need(data, "model")))
            coefs = tuple(float(c) for c in need(data, "coefficients"))
            if len(coefs) != model.n_coefficients:
                raise DataFormatError(
                    f"field 'coefficients': model '{model.name}' needs {model.n_coefficients}, "
                    f"got {len(coefs)}",
                    file=source,
                )
            validity = need(data, "validity")
            box = ValidityBox(
                thrust_n=Box(*map(float, need(validity, "thrust_n", "validity."))),
                voltage_v=Box(*map(float, need(validity, "voltage_v", "validity."))),
                throttle_pct=Box(*map(float, need(validity, "throttle_pct", "validity."))),
            )
            corr_raw = data.get("correction")
            correction = None
            if corr_raw is not None:
                correction = GammaCorrection(
                    coefficients=tuple(
                        float(c) for c in need(corr_raw, "coefficients", "correction.")
                    ),
                    voltage_v=Box(*map(float, need(corr_raw, "voltage_v", "correction."))),
                    loss=str(corr_raw.get("loss", "l2")),
                    metrics=dict(corr_raw.get("metrics", {})),
                    sources=tuple(corr_raw.get("sources", ())),
                )
            return cls(
                model=model.name,
                coefficients=coefs,
                throttle_scale=ThrottleScale.from_dict(need(data, "throttle_scale")),
                validity=box,
                loss=str(data.get("loss", "l2")),
                strategy=str(data.get("strategy", "unknown")),
                rotors_on_esc=data.get("rotors_on_esc"),
                thrust_meaning=str(data.get("thrust_meaning", "per_rotor")),
                metrics=dict(data.get("metrics", {})),
                selection=dict(data.get("selection", {})),
                sources=tuple(data.get("sources", ())),
                correction=correction,
                tool_version=str(data.get("tool_version", "")),
                created_utc=str(data.get("created_utc", "")),
            )
        except DataFormatError:
            raise
        except Exception as exc:  # wrong types inside the document
            raise DataFormatError(f"malformed map file: {exc}", file=source) from None


def file_sha256(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()
