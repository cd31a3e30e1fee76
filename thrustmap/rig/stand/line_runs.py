"""Reading a line stand outside a sweep: raw counts for ``thrustmap stand calibrate`` and a
firmware's own sequence (``thrustmap stand run``), read as a recording.

A sequence is started only here and only when asked; the stand's ``close`` (every way out of
the ``with`` block, Ctrl-C and SIGTERM included) resets a board whose firmware has no stop
command (``reset_stops``), so an interrupted sequence does not keep spinning the motor. While it
runs, every row is held against the reading interlocks (thrust, current, rpm, temperature, the
minimum cell voltage) and a stand that falls silent mid-sequence (a lost link) ends it: both
raise, and the way out stops the motor.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

from thrustmap.core.errors import ConfigError, SafetyError
from thrustmap.rig.interfaces import StandSample
from thrustmap.rig.interlocks import Limits, Reading, check
from thrustmap.rig.stand.line import LineStand, LineStandTimeout

log = logging.getLogger(__name__)

#: a firmware's own sequence prints its rows at least this often once started (the slowest seen,
#: MQTB's, pauses 2 s between its tests): silent longer, the link is taken as lost
SEQUENCE_SILENT_S = 5.0


@dataclass
class SequenceResult:
    samples: list[StandSample] = field(default_factory=list)
    throttles: list[float] = field(default_factory=list)  # the firmware's throttle, per sample
    ended: bool = False


def collect_values(
    stand: LineStand, field_name: str, count: int, timeout_s: float = 10.0
) -> list[float]:
    """``count`` readings of ``field_name`` from a streaming stand (no command is sent)."""
    values: list[float] = []
    deadline = stand.clock.now_s() + timeout_s
    while len(values) < count:
        for sample in stand.read_samples():
            value = getattr(sample, field_name)
            if value is not None:
                values.append(float(value))
        if stand.clock.now_s() >= deadline:
            raise LineStandTimeout(
                f"{stand.spec.name}: {len(values)} of {count} readings of {field_name} "
                f"within {timeout_s:g} s"
            )
        stand.clock.sleep_s(0.01)
    return values[:count]


def run_sequence(
    stand: LineStand,
    timeout_s: float,
    on_sample: Callable[[StandSample, float], None] | None = None,
    limits: Limits | None = None,
) -> SequenceResult:
    """Start the firmware's own sequence and read it to its end line; each row's throttle is
    the one the firmware reports (``on_sample(sample, throttle)`` as rows arrive). A row past
    ``limits`` raises ``SafetyError``, a stand silent for ``SEQUENCE_SILENT_S`` once rows came
    raises ``LineStandTimeout``: the caller's way out stops the motor."""
    if "throttle" not in stand.spec.columns:
        raise ConfigError(f"line stand '{stand.spec.name}' reports no throttle in its rows")
    limits = limits or Limits()
    result = SequenceResult()
    stand.drives_esc = True  # the rows' throttle is the firmware's own output
    stand.start_sequence()
    deadline = stand.clock.now_s() + timeout_s
    last_row_at: float | None = None
    while True:
        for sample in stand.read_samples():
            throttle = sample.throttle_native
            if throttle is None:
                continue
            last_row_at = stand.clock.now_s()
            _check_row(stand, sample, limits)
            result.samples.append(sample)
            result.throttles.append(throttle)
            if on_sample is not None:
                on_sample(sample, throttle)
        if stand.sequence_ended:
            break
        now = stand.clock.now_s()
        if last_row_at is not None and now - last_row_at > SEQUENCE_SILENT_S:
            raise LineStandTimeout(
                f"{stand.spec.name}: silent for {now - last_row_at:.1f} s in its own sequence "
                f"(after {len(result.samples)} rows): the link is taken as lost"
            )
        if now >= deadline:
            raise LineStandTimeout(
                f"{stand.spec.name}: no '{stand.spec.sequence_end}' within {timeout_s:g} s "
                f"({len(result.samples)} rows read)"
            )
        stand.clock.sleep_s(0.02)
    result.ended = True
    stand.sequence_started = False
    log.info("%s: sequence of %d rows read", stand.spec.name, len(result.samples))
    return result


def _check_row(stand: LineStand, sample: StandSample, limits: Limits) -> None:
    """A row of the firmware's sequence against the reading interlocks."""
    reading = Reading(
        thrust_n=sample.thrust_n,
        current_a=sample.current_a,
        voltage_v=sample.voltage_v,
        rpm=sample.rpm,
        temperature_c=sample.temperature_c,
        vibration_g=sample.vibration_g,
    )
    trip = check(limits, reading)
    if trip is not None:
        raise SafetyError(f"{stand.spec.name}: limit tripped in its own sequence: {trip.message}")
