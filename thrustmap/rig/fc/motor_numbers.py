"""``--motor``: the FC's own motor number everywhere, or ArduPilot's test-order letter.

``--motor N`` is the FC's motor N (ArduPilot output function MotorN, PX4 MOTOR N, Betaflight
motor N), whatever command the driver needs underneath. ArduPilot users may give the letter
its Motor Test page shows instead (``--motor A``); ``resolve_motor`` turns it into the motor
through the driver's frame table. Light on imports: the CLI uses it before opening anything.
"""

from __future__ import annotations

from typing import Any

from thrustmap.core.errors import ConfigError

MAX_MOTORS = 16


def parse_motor(text: str | int) -> tuple[int | None, int | None]:
    """``"3"`` -> (3, None) (1-based motor); ``"A"`` -> (None, 1) (test-order number)."""
    raw = str(text).strip()
    if raw.isdigit():
        number = int(raw)
        if not 1 <= number <= MAX_MOTORS:
            raise ConfigError(f"--motor must be 1..{MAX_MOTORS} (1-based), got {raw}")
        return number, None
    if len(raw) == 1 and raw.isalpha() and raw.upper() <= "P":
        return None, ord(raw.upper()) - ord("A") + 1
    raise ConfigError(
        f"--motor must be the FC's motor number (1, 2, ...) or an ArduPilot test-order letter "
        f"(A, B, ...), got {raw!r}"
    )


def resolve_motor(output: Any, text: str | int) -> int:
    """The 0-based FC motor for ``--motor`` on this output (letters need an ArduPilot FC)."""
    number, order = parse_motor(text)
    if number is not None:
        return number - 1
    assert order is not None
    to_motor = getattr(output, "motor_for_test_order", None)
    if to_motor is None:
        raise ConfigError(
            f"--motor {text}: test-order letters are ArduPilot's; give the motor number"
        )
    motor: int = to_motor(order)
    return motor


def motor_label(output: Any, motor: int) -> str:
    """ "motor 3 (test order A)" on ArduPilot, "motor 3 (output 3)" on PX4, else "motor 3"."""
    label = getattr(output, "motor_label", None)
    return str(label(motor)) if label is not None else f"motor {motor + 1}"
