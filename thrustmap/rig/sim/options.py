"""``sim://`` URL options, read in one place: every option a simulated device takes is parsed
here, against its type and range, and a bad one is refused naming that option as the user wrote
it (``sim://betaflight?rate_hz=0`` -> "sim option rate_hz=0: expected a rate > 0 Hz").
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from thrustmap.core.errors import ConfigError

#: motors a simulated flight controller may declare (as ``--motor`` accepts: 1..16)
MAX_SIM_MOTORS = 16
TRUE = frozenset({"1", "true", "yes", "on"})
FALSE = frozenset({"0", "false", "no", "off"})


def _refuse(key: str, raw: str, expected: str) -> ConfigError:
    return ConfigError(f"sim option {key}={raw!r}: expected {expected}")


def opt_int(
    options: Mapping[str, str],
    key: str,
    default: int,
    *,
    lo: int | None = None,
    hi: int | None = None,
    what: str = "an integer",
) -> int:
    """Integer option ``key`` (``default`` when absent) within ``lo..hi``."""
    if key not in options:
        return default
    raw = options[key]
    expected = what + (
        f" {lo}..{hi}" if lo is not None and hi is not None
        else f" >= {lo}" if lo is not None
        else f" <= {hi}" if hi is not None
        else ""
    )  # fmt: skip
    try:
        value = int(raw.strip())
    except ValueError:
        raise _refuse(key, raw, expected) from None
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        raise _refuse(key, raw, expected)
    return value


def opt_float(
    options: Mapping[str, str],
    key: str,
    default: float,
    *,
    minimum: float | None = None,
    positive: bool = False,
    maximum: float | None = None,
    what: str = "a number",
) -> float:
    """Finite number option ``key``: > 0 when ``positive``, within ``minimum..maximum``."""
    if key not in options:
        return default
    raw = options[key]
    bounds = []
    if positive:
        bounds.append("> 0")
    if minimum is not None:
        bounds.append(f">= {minimum:g}")
    if maximum is not None:
        bounds.append(f"<= {maximum:g}")
    expected = what + (" " + " and ".join(bounds) if bounds else "")
    try:
        value = float(raw.strip())
    except ValueError:
        raise _refuse(key, raw, expected) from None
    if (
        not math.isfinite(value)
        or (positive and not value > 0)
        or (minimum is not None and value < minimum)
        or (maximum is not None and value > maximum)
    ):
        raise _refuse(key, raw, expected)
    return value


def opt_flag(options: Mapping[str, str], key: str, default: bool) -> bool:
    """Yes/no option ``key``: 1/true/yes/on or 0/false/no/off; anything else is refused."""
    if key not in options:
        return default
    raw = options[key]
    word = raw.strip().lower()
    if word in TRUE:
        return True
    if word in FALSE:
        return False
    raise _refuse(key, raw, "1 or 0 (true/false, yes/no, on/off)")
