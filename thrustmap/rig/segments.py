"""The segments a sweep plan is made of, in percent of the throttle output's native scale:
``Hold`` and ``Ramp`` (every plan), and across voltage ``Discharge`` and ``PackChange`` (an
adaptive plan's voltage moves). Plain frozen values: no I/O. ``rig.plans`` builds plans from
them, ``rig.adaptive_plan`` chooses them one at a time, and ``rig.runner`` executes them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from thrustmap.core.errors import ConfigError


@dataclass(frozen=True)
class Hold:
    """Hold a throttle level. With ``settle``, hold until thrust settles (at most ``dwell_s``)
    and then record ``record_s`` more; otherwise hold exactly ``dwell_s``."""

    throttle_pct: float
    dwell_s: float
    settle: bool = False
    record_s: float = 1.0
    label: str = "hold"


@dataclass(frozen=True)
class Ramp:
    """Move linearly from ``start_pct`` to ``end_pct`` over ``duration_s``."""

    start_pct: float
    end_pct: float
    duration_s: float
    label: str = "ramp"


Segment = Hold | Ramp


@dataclass(frozen=True)
class Discharge:
    """Hold ``throttle_pct`` until the battery voltage under that load has fallen to
    ``until_v`` (the mean over ``record_s``) or ``max_s`` has passed; every interlock stays on
    (current, temperature, minimum cell voltage). Its last ``record_s`` is a settled point."""

    throttle_pct: float
    until_v: float
    max_s: float
    record_s: float = 1.0
    label: str = "discharge"


@dataclass(frozen=True)
class PackChange:
    """Stop the motor and verify the stop, ask for another pack (``message``), then check the
    voltage at rest moved toward ``wanted_v`` before anything spins again."""

    wanted_v: float  # what the pack should read at rest
    message: str
    label: str = "pack-change"


#: what an adaptive plan's run yields: holds, and across voltage its voltage moves
RunSegment = Hold | Ramp | Discharge | PackChange
#: a pack change must move the voltage at rest by at least this share
PACK_MOVE_MIN_REL = 0.02


def hold_segment(level: float, dwell_s: float, settle: bool, record_s: float, label: str) -> Hold:
    """A ``Hold``, refusing a dwell that is not positive."""
    if not 0 < dwell_s < math.inf:  # also NaN
        raise ConfigError(f"--dwell {dwell_s:g}: expected a positive number of seconds")
    if not 0 <= record_s < math.inf:
        raise ConfigError(f"--record {record_s:g}: expected a positive number of seconds")
    if settle and record_s > dwell_s:
        raise ConfigError(
            f"--record {record_s:g} s is longer than --dwell {dwell_s:g} s, the most a settling "
            "level is held: it could never be recorded; raise --dwell or lower --record"
        )
    return Hold(level, dwell_s, settle, record_s, label)
