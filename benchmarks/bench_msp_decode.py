"""MSP reply frames decoded per second by ``MspDecoder`` (v1 and v2).

Workload: the replies a motor-test host sees — MOTOR (16-byte payload) and ANALOG (9 bytes)
alternating, fed in 64-byte chunks as a serial read would return them. Two figures: frames
only (``MspFrame`` objects), and frames plus payload records (``Motor``/``Analog``).
Baselines printed beside them:

- a naive byte-at-a-time state-machine decoder written here (the classic client shape),
  producing the same ``MspFrame`` objects;
- the firmware's own rate: one request served per serial-task run, 100 Hz by default and at
  most 2000 Hz (serial_update_rate_hz) — the decoder needs only a tiny fraction of one core.

Run: .venv/bin/python benchmarks/bench_msp_decode.py
"""

from __future__ import annotations

import time

from thrustmap.protocols.msp.framing import (
    MspDecoder,
    MspDirection,
    MspFrame,
    MspVersion,
    crc8_dvb_s2,
    encode_reply,
)
from thrustmap.protocols.msp.messages import Analog, decode_reply
from thrustmap.protocols.msp.motor import Motor

FRAMES = 20_000
CHUNK = 64
FIRMWARE_DEFAULT_HZ = 100
FIRMWARE_MAX_HZ = 2000


def make_stream(version: MspVersion) -> bytes:
    motor = encode_reply(104, Motor((1000, 1200, 1350, 1000, 0, 0, 0, 0)).encode(), version)
    analog = encode_reply(110, Analog(16.21, 12.5, 340, 0).encode(), version)
    return (motor + analog) * (FRAMES // 2)


def naive_decode(stream: bytes) -> list[MspFrame]:
    """Byte-at-a-time state machine (v1 and v2) returning the good frames."""
    frames: list[MspFrame] = []
    state = 0
    v2 = False
    direction = MspDirection.REPLY
    size = cmd = 0
    need = 0
    body = bytearray()
    for b in stream:
        if state == 0:
            state = 1 if b == 0x24 else 0
        elif state == 1:
            v2 = b == 0x58
            state = 2 if b in (0x4D, 0x58) else 0
        elif state == 2:
            state = 3 if b in (0x3C, 0x3E, 0x21) else 0
            if state:
                direction = MspDirection(chr(b))
            body.clear()
            need = 5 if v2 else 2
        elif state == 3:  # header bytes
            body.append(b)
            if len(body) == need:
                size = body[3] | (body[4] << 8) if v2 else body[0]
                cmd = body[1] | (body[2] << 8) if v2 else body[1]
                state = 4 if size else 5
        elif state == 4:  # payload
            body.append(b)
            if len(body) == need + size:
                state = 5
        elif state == 5:  # checksum
            if v2:
                ok = crc8_dvb_s2(body) == b
            else:
                x = 0
                for c in body:
                    x ^= c
                ok = x == b
            if ok:
                version = MspVersion.V2 if v2 else MspVersion.V1
                payload = bytes(body[need:])
                frames.append(MspFrame(version, direction, cmd, payload, body[0] if v2 else 0))
            state = 0
    return frames


def bench(version: MspVersion) -> tuple[float, float, float]:
    stream = make_stream(version)
    chunks = [stream[i : i + CHUNK] for i in range(0, len(stream), CHUNK)]

    decoder = MspDecoder()
    started = time.perf_counter()
    frames: list[MspFrame] = []
    for chunk in chunks:
        frames += decoder.feed(chunk)
    ours = len(frames) / (time.perf_counter() - started)

    decoder = MspDecoder()
    started = time.perf_counter()
    n = 0
    for chunk in chunks:
        for frame in decoder.feed(chunk):
            decode_reply(frame)
            n += 1
    with_records = n / (time.perf_counter() - started)

    started = time.perf_counter()
    naive_frames = naive_decode(stream)
    naive = len(naive_frames) / (time.perf_counter() - started)
    assert naive_frames == frames and len(frames) == n == FRAMES
    return ours, with_records, naive


def main() -> None:
    print(f"MSP decode, {FRAMES} MOTOR+ANALOG replies in {CHUNK}-byte chunks")
    print(f"{'':<8}{'MspDecoder':>16}{'naive byte-at-a-time':>24}{'ratio':>7}{'+ records':>16}")
    for version in (MspVersion.V1, MspVersion.V2):
        ours, with_records, naive = bench(version)
        print(
            f"{version.value:<8}{ours:>11,.0f} fr/s{naive:>19,.0f} fr/s{ours / naive:>6.1f}x"
            f"{with_records:>11,.0f} fr/s"
        )
    print(
        f"firmware serves {FIRMWARE_DEFAULT_HZ} requests/s by default "
        f"({FIRMWARE_MAX_HZ} at most): one reply per request"
    )


if __name__ == "__main__":
    main()
