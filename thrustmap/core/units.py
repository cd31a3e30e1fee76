"""Throttle scales: one place that converts between native throttle units and percent.

A dataset, a map and a driver each carry the native scale of their throttle command
(ESC pulse in µs, DShot value, Crazyflie 16-bit command, percent, ...). Fitting works in
percent of that scale, as the seed paper does; exports convert back exactly (affine).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from thrustmap.core.errors import ConfigError

if TYPE_CHECKING:  # numpy is imported where arrays are converted: the CLI starts without it
    import numpy as np
    import numpy.typing as npt

    FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class ThrottleScale:
    """An affine throttle encoding: ``lo`` is 0 % and ``hi`` is 100 %."""

    name: str
    lo: float
    hi: float
    unit: str

    def __post_init__(self) -> None:
        if not self.hi > self.lo:
            raise ConfigError(
                f"throttle scale '{self.name}': range {self.lo:g}:{self.hi:g} needs LO < HI"
            )

    @property
    def span(self) -> float:
        return self.hi - self.lo

    @property
    def unit_label(self) -> str:
        """The unit as a person reads it ("µs"); ``unit`` stays the ASCII name in files."""
        return unit_label(self.unit)

    def describe(self) -> str:
        """The scale as a person reads it: ``pwm 1000..2000 µs``, ``norm 0..1 (normalised)``
        (a dimensionless scale is not followed by a bare "1")."""
        unit = self.unit_label
        tail = " (normalised)" if unit in ("1", "") else f" {unit}"
        return f"{self.name} {self.lo:g}..{self.hi:g}{tail}"

    def to_pct(self, native: npt.ArrayLike) -> FloatArray:
        import numpy as np

        out: FloatArray = (np.asarray(native, dtype=float) - self.lo) / self.span * 100.0
        return out

    def from_pct(self, pct: npt.ArrayLike) -> FloatArray:
        import numpy as np

        out: FloatArray = self.lo + np.asarray(pct, dtype=float) / 100.0 * self.span
        return out

    def with_range(self, lo: float, hi: float) -> ThrottleScale:
        return ThrottleScale(self.name, lo, hi, self.unit)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "lo": self.lo, "hi": self.hi, "unit": self.unit}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ThrottleScale:
        try:
            return cls(str(data["name"]), float(data["lo"]), float(data["hi"]), str(data["unit"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise ConfigError(f"throttle scale needs name, lo, hi and unit, got {data!r}") from exc


def unit_label(unit: str) -> str:
    """An ASCII unit name as shown to a person: "us" is written "µs"."""
    return "µs" if unit == "us" else unit


#: Encodings a throttle command can take on the wire (seed paper Table 1 and beyond).
SCALES: dict[str, ThrottleScale] = {
    s.name: s
    for s in (
        ThrottleScale("pwm", 1000.0, 2000.0, "us"),
        ThrottleScale("oneshot125", 125.0, 250.0, "us"),
        ThrottleScale("oneshot42", 42.0, 84.0, "us"),
        ThrottleScale("multishot", 5.0, 25.0, "us"),
        ThrottleScale("dshot", 48.0, 2047.0, "dshot"),
        ThrottleScale("crazyflie", 0.0, 65535.0, "cmd"),
        ThrottleScale("crazyflie-cmd", 10001.0, 60000.0, "cmd"),
        ThrottleScale("percent", 0.0, 100.0, "%"),
        ThrottleScale("duty8", 0.0, 255.0, "duty"),  # an 8-bit analogWrite() duty
        ThrottleScale("norm", 0.0, 1.0, "1"),
        ThrottleScale("norm-sym", -1.0, 1.0, "1"),
    )
}


#: Where each encoding's endpoints can lie on the wire (its own units), wider than its standard
#: span for the ESCs and firmware that calibrate their own: a ``--range`` outside them is
#: another encoding's or another unit's (percent typed for µs, milliseconds for µs).
WIRE_BOUNDS: dict[str, tuple[float, float]] = {
    "pwm": (500.0, 2500.0),
    "oneshot125": (60.0, 500.0),
    "oneshot42": (20.0, 170.0),
    "multishot": (2.0, 50.0),
    "dshot": (0.0, 2047.0),
    "crazyflie": (0.0, 65535.0),
    "crazyflie-cmd": (0.0, 65535.0),
    "percent": (0.0, 100.0),
    "duty8": (0.0, 255.0),
    "norm": (0.0, 1.0),
    "norm-sym": (-1.0, 1.0),
}
#: a range narrower than this share of the encoding's standard span is another unit's
#: (a fraction typed for percent, percent for DShot values)
MIN_RANGE_SHARE = 0.25


def range_problem(name: str, lo: float, hi: float) -> str | None:
    """Why endpoints ``lo..hi`` cannot be encoding ``name``'s (None: they can)."""
    base = SCALES.get(name)
    bounds = WIRE_BOUNDS.get(name)
    if base is None or bounds is None:
        return None
    unit = f" {base.unit_label}" if base.unit_label not in ("1", "") else ""
    if lo < bounds[0] or hi > bounds[1]:
        return (
            f"{lo:g}:{hi:g} lies outside what {name} can be on the wire "
            f"({bounds[0]:g}..{bounds[1]:g}{unit}; standard {base.lo:g}:{base.hi:g}): "
            "is it in another unit?"
        )
    if hi - lo < MIN_RANGE_SHARE * base.span:
        return (
            f"{lo:g}:{hi:g} spans {hi - lo:g}{unit}, under a quarter of {name}'s "
            f"{base.lo:g}:{base.hi:g}{unit}: is it in another unit?"
        )
    return None


def scale(name: str) -> ThrottleScale:
    """Look up a named throttle scale, with an error listing the known ones."""
    try:
        return SCALES[name]
    except KeyError:
        raise ConfigError(
            f"unknown throttle scale '{name}'; expected one of: {', '.join(SCALES)}"
        ) from None


def parse_range(text: str, what: str) -> tuple[float, float]:
    """Parse ``LO:HI`` (numbers, LO < HI) for option ``what``."""
    parts = text.split(":")
    if len(parts) != 2:
        raise ConfigError(f"{what}: expected LO:HI, got '{text}'")
    try:
        lo, hi = float(parts[0]), float(parts[1])
    except ValueError:
        raise ConfigError(f"{what}: expected two numbers LO:HI, got '{text}'") from None
    if not lo < hi:
        raise ConfigError(f"{what}: expected LO < HI, got '{text}'")
    return lo, hi
