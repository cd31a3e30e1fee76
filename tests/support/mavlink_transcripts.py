"""Record the MAVLink driver fixtures from the simulated vehicles, and replay them.

``python -m support.mavlink_transcripts [DIR]`` (default ``fixtures/transcripts``) runs
every scenario below with ``Px4ThrottleOutput``/``ArduPilotThrottleOutput`` against a simulated
vehicle (``ConstantPlant``: no dynamics, so decoded values do not depend on exact timing),
through the project's ``record://`` tap, and writes ``<name>.jsonl``. ``replay_scenario`` runs the
same scenario code through ``replay://`` (strict): the driver must write exactly the recorded
bytes, the stop sequence included. Everything runs on a ``SimClock``; nothing sleeps.

A scenario is a fixed sequence of driver calls (clock sleeps between them), never a loop that
depends on timing, so replay reproduces every write.
"""

from __future__ import annotations

import argparse
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from thrustmap.core.clock import Clock, SimClock
from thrustmap.core.errors import ThrustmapError
from thrustmap.protocols.mavlink.link import MavlinkSerialLink
from thrustmap.protocols.transcript import TranscriptWriter, read_transcript
from thrustmap.protocols.urlhandlers.protocol_record import RecordingSerial
from thrustmap.protocols.urlhandlers.protocol_replay import ReplaySerial
from thrustmap.protocols.urlhandlers.protocol_sim import SimSerial
from thrustmap.rig.fc.ardupilot import ArduPilotThrottleOutput
from thrustmap.rig.fc.mavlink_output import MavlinkThrottleOutput
from thrustmap.rig.fc.px4 import Px4ThrottleOutput
from thrustmap.rig.sim.mavlink_peers import ArduPilotVehicle, PX4Vehicle
from thrustmap.rig.sim.mavlink_vehicle import SimMavlinkVehicle
from thrustmap.rig.sim.plant import ConstantPlant

log = logging.getLogger(__name__)

DEFAULT_DIR = Path("fixtures") / "transcripts"


@dataclass
class ScenarioResult:
    """What a scenario saw, decoded (compared between recording and replay)."""

    identity: dict[str, object] | None = None
    telemetry: list[tuple[Any, ...]] = field(default_factory=list)
    error: str | None = None
    error_type: str | None = None
    stop_verified: bool | None = None


@dataclass(frozen=True)
class Scenario:
    name: str
    inner: str  # what the transcript header names as the recorded peer
    vehicle: Callable[[], SimMavlinkVehicle]
    driver: type[MavlinkThrottleOutput]
    script: Callable[[MavlinkThrottleOutput, Clock, ScenarioResult], None]


def _telemetry_row(out: MavlinkThrottleOutput) -> tuple[Any, ...]:
    tel = out.read_telemetry()
    return (tel.voltage_v, tel.current_a, tel.rpm, tel.temperature_c)


def _spin(levels: Sequence[float], keepalives: int) -> Callable[..., None]:
    """identify; for each level: set it, then ``keepalives`` × (0.5 s, keepalive, telemetry)."""

    def script(out: MavlinkThrottleOutput, clock: Clock, result: ScenarioResult) -> None:
        result.identity = out.identify().to_dict()
        for level in levels:
            out.set_throttle({0: level})
            for _ in range(keepalives):
                clock.sleep_s(0.5)
                out.keepalive()
                result.telemetry.append(_telemetry_row(out))

    return script


def _refused(level: float) -> Callable[..., None]:
    def script(out: MavlinkThrottleOutput, clock: Clock, result: ScenarioResult) -> None:
        result.identity = out.identify().to_dict()
        out.set_throttle({0: level})  # raises: the vehicle refuses

    return script


SCENARIOS: dict[str, Scenario] = {
    s.name: s
    for s in (
        Scenario(
            "px4_spin",
            "sim://px4?motors=4",
            lambda: PX4Vehicle(ConstantPlant()),
            Px4ThrottleOutput,
            _spin([0.5, 0.3], keepalives=6),  # 3 s per level: past PX4's own 2 s / 3 s timeout
        ),
        Scenario(
            "px4_denied_safety",
            "sim://px4?motors=4&safety=1",
            lambda: PX4Vehicle(ConstantPlant(), safety_on=True),
            Px4ThrottleOutput,
            _refused(0.2),
        ),
        Scenario(
            "ardupilot_spin",
            "sim://ardupilot?motors=4",
            lambda: ArduPilotVehicle(ConstantPlant()),
            ArduPilotThrottleOutput,
            _spin([1500.0, 1300.0], keepalives=6),
        ),
        Scenario(
            "ardupilot_not_landed",
            "sim://ardupilot?motors=4&landed=0",
            lambda: ArduPilotVehicle(ConstantPlant(), landed=False),
            ArduPilotThrottleOutput,
            _refused(1200.0),
        ),
    )
}


def run_scenario(scenario: Scenario, link: Any, clock: Clock) -> ScenarioResult:
    """Run one scenario on ``link``; the driver's context manager stops and closes."""
    result = ScenarioResult()
    out = scenario.driver(link, clock)
    try:
        with out:
            scenario.script(out, clock, result)
    except ThrustmapError as exc:
        result.error, result.error_type = str(exc), type(exc).__name__
    result.stop_verified = out.last_stop_verified
    return result


def record_scenario(name: str, directory: str | Path = DEFAULT_DIR) -> tuple[Path, ScenarioResult]:
    """Record ``<directory>/<name>.jsonl`` from the simulated vehicle."""
    scenario = SCENARIOS[name]
    path = Path(directory) / f"{name}.jsonl"
    path.parent.mkdir(parents=True, exist_ok=True)
    clock = SimClock()
    inner = SimSerial(scenario.vehicle(), clock, timeout=0, name=scenario.inner)
    writer = TranscriptWriter(
        path,
        inner=scenario.inner,
        origin_s=clock.now_s(),
        extra={"clock": "SimClock", "generator": "support.mavlink_transcripts"},
    )
    port = RecordingSerial(inner, writer, clock, timeout=0)
    result = run_scenario(scenario, MavlinkSerialLink(port, clock, name=str(path)), clock)
    return path, result


def replay_scenario(
    name: str, directory: str | Path = DEFAULT_DIR, *, strict: bool = True
) -> tuple[ScenarioResult, ReplaySerial]:
    """Run ``name`` against its transcript (strict replay); returns the result and the port."""
    scenario = SCENARIOS[name]
    clock = SimClock()
    path = Path(directory) / f"{name}.jsonl"
    port = ReplaySerial(read_transcript(path), strict=strict, clock=clock, timeout=0)
    result = run_scenario(scenario, MavlinkSerialLink(port, clock, name=f"replay://{path}"), clock)
    return result, port


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    return bool(a == b)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("directory", nargs="?", default=str(DEFAULT_DIR))
    parser.add_argument("--only", action="append", choices=sorted(SCENARIOS))
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    for name in args.only or sorted(SCENARIOS):
        path, recorded = record_scenario(name, args.directory)
        replayed, port = replay_scenario(name, args.directory)
        port.assert_consumed()
        if not _same(recorded, replayed):
            raise SystemExit(f"{path}: replay differs from the recording: {replayed} != {recorded}")
        log.info("wrote %s (%s)", path, recorded.error_type or "completed")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
