"""ArduCopter motor numbering: the FC's motor N (output function MotorN) vs the test order.

MAV_CMD_DO_MOTOR_TEST's instance is a TEST-ORDER number (1 = "A", 2 = "B", ... as the Motor
Test page shows them), not the motor number: on a plus-frame quad, test instance 1 drives
Motor3 (front). Each frame's table below lists, for Motor1..MotorN, its test-order number, as
ArduCopter's motor matrix defines them (FRAME_CLASS, FRAME_TYPE). thrustmap's ``--motor N``
always means MotorN; these tables translate it to the instance the command needs. Pure data.
"""

from __future__ import annotations

from dataclasses import dataclass

from thrustmap.core.errors import ConfigError

FRAME_CLASSES = {
    1: "QUAD",
    2: "HEXA",
    3: "OCTA",
    4: "OCTAQUAD",
    5: "Y6",
    12: "DODECAHEXA",
}
FRAME_TYPES = {
    0: "PLUS",
    1: "X",
    2: "V",
    3: "H",
    4: "VTAIL",
    5: "ATAIL",
    6: "PLUSREV",
    10: "Y6B",
    11: "Y6F",
    12: "BF_X",
    13: "DJI_X",
    14: "CW_X",
    15: "I",
    16: "NYT_PLUS",
    17: "NYT_X",
    18: "BF_X_REV",
    19: "Y4",
}
_ANY_TYPE = -1  # a class whose table does not depend on FRAME_TYPE (Y6 default)

#: (FRAME_CLASS, FRAME_TYPE) -> test-order number of Motor1, Motor2, ...
TEST_ORDER: dict[tuple[int, int], tuple[int, ...]] = {
    # quad
    (1, 0): (2, 4, 1, 3),
    (1, 1): (1, 3, 4, 2),
    (1, 2): (1, 3, 4, 2),
    (1, 3): (1, 3, 4, 2),
    (1, 4): (1, 3, 4, 2),
    (1, 5): (1, 3, 4, 2),
    (1, 6): (2, 4, 1, 3),
    (1, 12): (2, 1, 3, 4),
    (1, 13): (1, 4, 3, 2),
    (1, 14): (1, 2, 3, 4),
    (1, 16): (2, 4, 1, 3),
    (1, 17): (1, 3, 4, 2),
    (1, 18): (2, 1, 3, 4),
    (1, 19): (1, 2, 3, 4),
    # hexa
    (2, 0): (1, 4, 5, 2, 6, 3),
    (2, 1): (2, 5, 6, 3, 1, 4),
    (2, 3): (2, 5, 6, 3, 1, 4),
    (2, 13): (1, 6, 5, 4, 3, 2),
    (2, 14): (1, 2, 3, 4, 5, 6),
    # octa
    (3, 0): (1, 5, 2, 4, 8, 6, 7, 3),
    (3, 1): (1, 5, 2, 4, 8, 6, 7, 3),
    (3, 2): (7, 3, 6, 4, 8, 2, 1, 5),
    (3, 3): (1, 5, 2, 4, 8, 6, 7, 3),
    (3, 15): (5, 1, 6, 8, 4, 2, 3, 7),
    (3, 13): (1, 8, 7, 6, 5, 4, 3, 2),
    (3, 14): (1, 2, 3, 4, 5, 6, 7, 8),
    # octa-quad
    (4, 0): (1, 7, 5, 3, 8, 2, 4, 6),
    (4, 1): (1, 7, 5, 3, 8, 2, 4, 6),
    (4, 2): (1, 7, 5, 3, 8, 2, 4, 6),
    (4, 3): (1, 7, 5, 3, 8, 2, 4, 6),
    (4, 14): (1, 2, 3, 4, 5, 6, 7, 8),
    (4, 12): (3, 1, 5, 7, 4, 2, 6, 8),
    (4, 18): (3, 1, 5, 7, 4, 2, 6, 8),
    # Y6
    (5, 10): (1, 2, 3, 4, 5, 6),
    (5, 11): (3, 1, 5, 4, 2, 6),
    (5, _ANY_TYPE): (2, 5, 6, 4, 1, 3),
    # dodeca-hexa
    (12, 0): tuple(range(1, 13)),
    (12, 1): tuple(range(1, 13)),
}


def test_letter(order: int) -> str:
    """Test-order number -> the letter ArduPilot's Motor Test page shows (1 -> "A")."""
    if not 1 <= order <= 26:
        raise ConfigError(f"test-order number must be 1..26, got {order}")
    return chr(ord("A") + order - 1)


def parse_test_letter(text: str) -> int | None:
    """ "A" / "b" -> 1 / 2; anything else -> None."""
    t = text.strip().upper()
    if len(t) == 1 and "A" <= t <= "Z":
        return ord(t) - ord("A") + 1
    return None


@dataclass(frozen=True)
class MotorOrder:
    """How one frame numbers its motors. ``test_order[i]`` is Motor(i+1)'s test-order number."""

    frame: str
    test_order: tuple[int, ...]
    known: bool = True  # False: the frame is not in the table (identity assumed)

    @property
    def motor_count(self) -> int:
        return len(self.test_order)

    def instance_for(self, motor: int) -> int:
        """0-based FC motor (Motor``motor+1``) -> DO_MOTOR_TEST instance (test order)."""
        if not 0 <= motor < len(self.test_order):
            raise ConfigError(
                f"motor {motor + 1} does not exist on this {self.frame} frame "
                f"({len(self.test_order)} motors)"
            )
        return self.test_order[motor]

    def motor_for(self, instance: int) -> int:
        """DO_MOTOR_TEST instance (test order) -> 0-based FC motor."""
        try:
            return self.test_order.index(instance)
        except ValueError:
            raise ConfigError(
                f"test order {test_letter(instance)} does not exist on this {self.frame} frame"
            ) from None

    def label(self, motor: int) -> str:
        """ "motor 3 (test order A)"."""
        return f"motor {motor + 1} (test order {test_letter(self.instance_for(motor))})"


def motor_order(frame_class: int | None, frame_type: int | None, motor_count: int) -> MotorOrder:
    """The table for FRAME_CLASS/FRAME_TYPE; unknown frames get test order = motor number."""
    cls_name = FRAME_CLASSES.get(frame_class or 0, f"FRAME_CLASS {frame_class}")
    type_name = FRAME_TYPES.get(frame_type if frame_type is not None else -99, f"{frame_type}")
    if frame_class is not None:
        table = TEST_ORDER.get((frame_class, frame_type if frame_type is not None else -99))
        if table is None:
            table = TEST_ORDER.get((frame_class, _ANY_TYPE))
        if table is not None:
            return MotorOrder(f"{cls_name} {type_name}", table)
    count = max(1, motor_count)
    return MotorOrder(f"{cls_name} {type_name}", tuple(range(1, count + 1)), known=False)
