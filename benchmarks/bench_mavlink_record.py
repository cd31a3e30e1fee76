"""record:// on a PX4 GCS link: transcript size and keep-alive timing, ours vs the old link.

The baseline is the recording a user actually got before (``px4/probe`` from the firmware
transcripts: PX4 v1.17 SITL, recorded through ``record://`` with the old link that read one
byte per call, so one JSON line per byte). Ours: the same FC -> host bytes, played at their
recorded times into today's driver (``identify()``, as ``probe`` does) through ``record://``;
the link reads a whole burst per call, so one event per read call. Then a 6 s spin against the
simulated PX4 with its 50 Hz telemetry flood, recorded: the largest gap between keep-alives.

Run: .venv/bin/python benchmarks/bench_mavlink_record.py [firmware-transcripts dir]
(default ../shared/data/firmware-transcripts; the first part is skipped without it).
"""

from __future__ import annotations

import logging
import sys
import tempfile
from pathlib import Path
from typing import Any

from thrustmap.core.clock import SimClock
from thrustmap.protocols.mavlink import codec as mav
from thrustmap.protocols.mavlink.link import MavlinkSerialLink, open_mavlink
from thrustmap.protocols.transcript import Transcript, TranscriptWriter, read_transcript
from thrustmap.protocols.urlhandlers.protocol_record import RecordingSerial
from thrustmap.protocols.urlhandlers.protocol_sim import SimSerial
from thrustmap.rig.devices.urls import load_sim_peers
from thrustmap.rig.fc.mavlink import open_mavlink_output

DEFAULT_DIR = (
    Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "firmware-transcripts"
)


class PlayedFc:
    """The FC side of a transcript at its recorded times; host writes are ignored."""

    def __init__(self, transcript: Transcript) -> None:
        self._reads = [(e.time_s, e.data) for e in transcript.events if e.direction == "r"]
        self._next = 0
        self._origin: float | None = None

    def write(self, data: bytes, now_s: float) -> None:
        pass

    def read(self, now_s: float) -> bytes:
        if self._origin is None:
            self._origin = now_s
        out = bytearray()
        while self._next < len(self._reads) and self._reads[self._next][0] <= now_s - self._origin:
            out += self._reads[self._next][1]
            self._next += 1
        return bytes(out)


def _reads(path: Path) -> tuple[int, int, int]:
    t = read_transcript(path)
    reads = [e for e in t.events if e.direction == "r"]
    return len(reads), sum(len(e.data) for e in reads), path.stat().st_size


def probe_size(directory: Path, out_dir: Path) -> None:
    old_path = directory / "px4" / "probe.jsonl"
    if not old_path.is_file():
        print(f"skipped the size comparison: {old_path} not found")
        return
    old = read_transcript(old_path)
    clock = SimClock()
    new_path = out_dir / "probe_now.jsonl"
    writer = TranscriptWriter(new_path, inner="played px4/probe", origin_s=clock.now_s())
    port: Any = RecordingSerial(SimSerial(PlayedFc(old), clock, timeout=0), writer, clock)
    out = open_mavlink_output(MavlinkSerialLink(port, clock), clock)
    ident = out.identify()
    port.close()
    o_events, o_bytes, o_size = _reads(old_path)
    n_events, n_bytes, n_size = _reads(new_path)
    print(f"PX4 probe (real SITL bytes), identify -> {ident.kind} {ident.firmware_version}")
    print(f"{'':28}{'read events':>12}{'bytes read':>12}{'bytes/event':>12}{'file kB':>10}")
    print(
        f"{'old link (1 byte per read)':28}{o_events:12d}{o_bytes:12d}"
        f"{o_bytes / o_events:12.1f}{o_size / 1000:10.0f}"
    )
    print(
        f"{'ours (one read per burst)':28}{n_events:12d}{n_bytes:12d}"
        f"{n_bytes / n_events:12.1f}{n_size / 1000:10.0f}"
    )
    print(f"bytes per read event: x{(n_bytes / n_events) / (o_bytes / o_events):.0f}")


def flood_keepalives(out_dir: Path) -> None:
    load_sim_peers()  # sim://px4 (registering is the rig's job, not an import's side effect)
    clock = SimClock()
    path = out_dir / "flood.jsonl"
    out = open_mavlink_output(
        open_mavlink(f"record://sim://px4?flood=1&file={path}", clock=clock), clock
    )
    with out:
        out.identify()
        out.set_throttle({0: 0.2})
        for _ in range(12):
            clock.sleep_s(0.5)
            out.keepalive()
    t = read_transcript(path)
    codec = mav.MavlinkCodec()
    times = [
        e.time_s
        for e in t.events
        if e.direction == "w"
        for m in codec.feed(e.data)
        if m.get_type() == "COMMAND_LONG" and int(m.command) == mav.MAV_CMD_ACTUATOR_TEST
    ]
    gaps = [b - a for a, b in zip(times, times[1:], strict=False)]
    received = sum(len(e.data) for e in t.events if e.direction == "r")
    span_s = t.events[-1].time_s
    print(
        f"\nsimulated PX4 flood through record://: {received / span_s / 1000:.1f} kB/s read, "
        f"{len(times)} ACTUATOR_TEST sent, largest gap {max(gaps):.2f} s "
        f"(keep-alive every 0.5 s, firmware timeout 2 s); "
        f"stop verified: {out.last_stop_verified}"
    )


def main() -> None:
    logging.basicConfig(level=logging.ERROR)
    directory = Path(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT_DIR
    with tempfile.TemporaryDirectory() as tmp:
        probe_size(directory, Path(tmp))
        flood_keepalives(Path(tmp))


if __name__ == "__main__":
    main()
