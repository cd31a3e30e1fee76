"""Trim a recorded flight to what `gamma live` and `flightlog extract` read (for fixtures/firmware/).

    python -m support.trim_logs tlog IN OUT             # keep telemetry.TYPES from the vehicle
    python -m support.trim_logs dataflash IN OUT TYPE,TYPE,...
    python -m support.trim_logs ulog IN OUT             # keep ulog.TOPICS' data

Each keeps the kept messages' bytes exactly (a .tlog record, a DataFlash message, a ULog data
message) and every definition, so the readers decode the same values from the smaller file;
it prints the sizes. Whether a trimmed file gives the same Df is checked by running the real
commands on both (done when the fixture was made; see fixtures/firmware/*/README.md).
"""

from __future__ import annotations

import struct
import sys
from pathlib import Path


def trim_tlog(src: Path, dst: Path, keep: frozenset[str]) -> None:
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(str(src), dialect="ardupilotmega")
    with dst.open("xb") as out:
        while True:
            msg = conn.recv_msg()
            if msg is None:
                break
            if msg.get_type() not in keep:
                continue
            stamp = int(round(msg._timestamp * 1e6))
            out.write(struct.pack(">Q", stamp) + bytes(msg.get_msgbuf()))


def trim_dataflash(src: Path, dst: Path, keep: frozenset[str]) -> None:
    data = src.read_bytes()
    lengths: dict[int, int] = {128: 89}
    names: dict[int, str] = {128: "FMT"}
    out = bytearray()
    pos = 0
    while pos + 3 <= len(data):
        if data[pos] != 0xA3 or data[pos + 1] != 0x95:
            pos += 1  # resynchronise as a reader does
            continue
        kind = data[pos + 2]
        if kind == 128:
            t, length = data[pos + 3], data[pos + 4]
            lengths[t] = length
            names[t] = data[pos + 5 : pos + 9].rstrip(b"\0").decode("ascii", "replace")
        length = lengths.get(kind)
        if length is None:
            pos += 1
            continue
        if names[kind] in keep or kind == 128:
            out += data[pos : pos + length]
        pos += length
    dst.open("xb").write(bytes(out))


def trim_ulog(src: Path, dst: Path, topics: frozenset[str]) -> None:
    data = src.read_bytes()
    out = bytearray(data[:16])
    pos = 16
    kept_ids: set[int] = set()
    while pos + 3 <= len(data):
        size, kind = struct.unpack_from("<HB", data, pos)
        end = pos + 3 + size
        if end > len(data):
            break
        if kind == ord("B") and any(data[pos + 3 + 8 : pos + 3 + 16]):
            raise ValueError(f"{src}: ULog with incompatible flags (appended data): not trimmed")
        keep = True
        if kind == ord("A"):
            msg_id = struct.unpack_from("<H", data, pos + 4)[0]
            name = data[pos + 6 : end].decode("ascii", "replace")
            if name in topics:
                kept_ids.add(msg_id)
            else:
                keep = False
        elif kind == ord("D"):
            keep = struct.unpack_from("<H", data, pos + 3)[0] in kept_ids
        if keep:
            out += data[pos:end]
        pos = end
    dst.open("xb").write(bytes(out))


def main(argv: list[str]) -> None:
    kind, src, dst = argv[0], Path(argv[1]), Path(argv[2])
    if kind == "tlog":
        from thrustmap.flightlogs.telemetry import TYPES

        trim_tlog(src, dst, frozenset(TYPES))
    elif kind == "dataflash":
        trim_dataflash(src, dst, frozenset(argv[3].split(",")))
    elif kind == "ulog":
        from thrustmap.flightlogs.ulog import TOPICS

        trim_ulog(src, dst, frozenset(TOPICS))
    else:
        raise SystemExit(f"unknown kind {kind!r}: tlog, dataflash or ulog")
    print(f"{src} {src.stat().st_size} B -> {dst} {dst.stat().st_size} B")


if __name__ == "__main__":
    main(sys.argv[1:])
