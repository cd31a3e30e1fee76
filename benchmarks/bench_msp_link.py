"""The MSP link in real time: request/response rate and paced command rate with jitter.

Against the simulated Betaflight peer (``sim://betaflight``, the xNova physics behind it), on
the real monotonic clock, through the real driver (``MspThrottleOutput``):

1. Round trips per second (SET_MOTOR then MOTOR, over and over) with the peer's serial task at
   the firmware default (100 Hz: one request served per run), at the firmware maximum (2000 Hz,
   ``serial_update_rate_hz``) and with no limit at all (the driver's own ceiling). Baseline: the
   firmware's ~100 request/response pairs per second (msp.md).
2. A paced loop sending SET_MOTOR at 50, 100 and 200 Hz requested, sleeping to absolute
   deadlines, waiting for each ack as the driver does; achieved rate and the inter-command
   intervals (p50, p99, max |interval - period|). Baseline: the requested period.
3. 200 Hz without waiting for the ack (raw frames on the driver's port, a mode the driver does
   not have): how the acks and the backlog behave.

Everything runs in-process (no sockets); about 20 s in total.
Run: .venv/bin/python benchmarks/bench_msp_link.py [seconds per measurement, default 2]
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from thrustmap.core.clock import MonotonicClock
from thrustmap.protocols.msp.framing import MspCommand, MspDecoder, encode_request
from thrustmap.protocols.msp.motor import MSP_MOTOR_STOP, SetMotor
from thrustmap.protocols.transport import open_transport
from thrustmap.rig.fc.msp import MspThrottleOutput
from thrustmap.rig.sim import peers

FIRMWARE_DEFAULT_HZ = 100.0
FIRMWARE_MAX_HZ = 2000.0
TEST_US = 1100  # a low spin: 10 % of 1000..2000 µs


def open_fc(rate_hz: int, clock: MonotonicClock) -> MspThrottleOutput:
    """The simulated FC with its serial task at ``rate_hz`` (0: no limit)."""
    rate = rate_hz or "unlimited"  # sim option rate_hz must be > 0, or "unlimited"
    peers.reset_benches()
    url = f"sim://betaflight?bench=link&rotors=1&seed=1&protocol=PWM&rate_hz={rate}"
    fc = MspThrottleOutput(open_transport(url, clock=clock, timeout=0), clock)
    fc.identify()  # identity, not ARMED, arming disabled: as before any motor test
    return fc


def set_motor_payload(value_us: int) -> bytes:
    return SetMotor((value_us,) + (MSP_MOTOR_STOP,) * 7).encode()


@dataclass
class RoundTrips:
    per_s: float
    p50_ms: float
    p99_ms: float


def round_trips(rate_hz: int, seconds: float) -> RoundTrips:
    """SET_MOTOR / MOTOR request-response pairs for ``seconds``; every request counts."""
    clock = MonotonicClock()
    payload = set_motor_payload(TEST_US)
    latencies: list[float] = []
    fc = open_fc(rate_hz, clock)
    with fc:  # its exit sends the stop and verifies it
        start = clock.now_s()
        end = start + seconds
        while True:
            t = clock.now_s()
            if t >= end:
                break
            fc.request(MspCommand.SET_MOTOR, payload)
            t_mid = clock.now_s()
            fc.request(MspCommand.MOTOR)
            t_end = clock.now_s()
            latencies += [t_mid - t, t_end - t_mid]
        elapsed = clock.now_s() - start
    lat = np.array(latencies) * 1e3
    return RoundTrips(
        len(latencies) / elapsed, float(np.percentile(lat, 50)), float(np.percentile(lat, 99))
    )


@dataclass
class Paced:
    requested_hz: float
    achieved_hz: float
    p50_ms: float
    p99_ms: float
    p99_jitter_ms: float
    max_jitter_ms: float
    behind_s: float  # how far the last command was behind its deadline
    acks_hz: float | None = None
    ack_backlog_s: float | None = None


def _stats(
    requested_hz: float, sends: npt.NDArray[np.float64], deadlines: npt.NDArray[np.float64]
) -> Paced:
    period = 1.0 / requested_hz
    intervals = np.diff(sends)
    jitter = np.abs(intervals - period) * 1e3
    return Paced(
        requested_hz,
        (len(sends) - 1) / float(sends[-1] - sends[0]),
        float(np.percentile(intervals, 50) * 1e3),
        float(np.percentile(intervals, 99) * 1e3),
        float(np.percentile(jitter, 99)),
        float(jitter.max()),
        float(sends[-1] - deadlines[-1]),
    )


def paced(requested_hz: float, seconds: float) -> Paced:
    """SET_MOTOR every 1/``requested_hz`` s to absolute deadlines, each waiting for its ack,
    for ``seconds``. A late command is sent at once (no deadline is skipped)."""
    clock = MonotonicClock()
    period = 1.0 / requested_hz
    n = int(seconds * requested_hz)
    sends = np.empty(n)
    fc = open_fc(int(FIRMWARE_DEFAULT_HZ), clock)
    with fc:
        t0 = clock.now_s() + period
        deadlines = t0 + period * np.arange(n, dtype=np.float64)
        sent = 0
        for k in range(n):
            if clock.now_s() - t0 >= seconds:  # fell behind: stop at the time budget
                break
            clock.sleep_s(deadlines[k] - clock.now_s())
            sends[k] = clock.now_s()
            fc.set_throttle({0: TEST_US + k % 50})  # native µs (PWM), every one a change
            sent += 1
    return _stats(requested_hz, sends[:sent], deadlines[:sent])


def paced_no_ack(requested_hz: float, seconds: float) -> Paced:
    """The same loop writing raw SET_MOTOR frames without waiting for the ack; acks are
    drained as they arrive. (The driver has no such mode; this measures what it would do.)"""
    clock = MonotonicClock()
    period = 1.0 / requested_hz
    n = int(seconds * requested_hz)
    sends = np.empty(n)
    acks: list[float] = []
    decoder = MspDecoder()
    fc = open_fc(int(FIRMWARE_DEFAULT_HZ), clock)
    with fc:
        port = fc.port

        def drain() -> None:
            data = port.read(max(1, port.in_waiting))
            for frame in decoder.feed(data):
                if frame.cmd == MspCommand.SET_MOTOR:
                    acks.append(clock.now_s())

        t0 = clock.now_s() + period
        deadlines = t0 + period * np.arange(n, dtype=np.float64)
        for k in range(n):
            clock.sleep_s(deadlines[k] - clock.now_s())
            sends[k] = clock.now_s()
            port.write(encode_request(MspCommand.SET_MOTOR, set_motor_payload(TEST_US + k % 50)))
            drain()
        acks_in_window = len(acks)
        window_s = clock.now_s() - sends[0]
        give_up = clock.now_s() + n / FIRMWARE_DEFAULT_HZ + 1.0
        while len(acks) < n and clock.now_s() < give_up:
            clock.sleep_s(0.001)
            drain()
        # the context manager's exit sends the stop and verifies it behind the backlog
    out = _stats(requested_hz, sends, deadlines)
    out.acks_hz = acks_in_window / window_s
    out.ack_backlog_s = (acks[-1] - sends[-1]) if len(acks) == n else float("nan")
    return out


def main() -> None:
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 2.0
    print("MSP request/response against sim://betaflight, real time (MonotonicClock)")
    print(
        f"{'peer serial task':<28} {'requests/s':>11} {'firmware baseline':>18} "
        f"{'latency p50':>12} {'p99':>8}"
    )
    for rate, label, baseline in (
        (100, "100 Hz (firmware default)", f"~{FIRMWARE_DEFAULT_HZ:.0f}/s"),
        (2000, "2000 Hz (firmware maximum)", f"<= {FIRMWARE_MAX_HZ:.0f}/s"),
        (0, "unlimited (driver ceiling)", "-"),
    ):
        r = round_trips(rate, seconds)
        print(
            f"{label:<28} {r.per_s:>11.1f} {baseline:>18} {r.p50_ms:>9.2f} ms {r.p99_ms:>5.2f} ms"
        )

    print()
    print("Paced SET_MOTOR, each waiting for its ack (the driver), peer at 100 Hz, real time")
    print(
        f"{'requested':>9} {'achieved':>9} {'period':>8} {'interval p50':>13} {'p99':>8} "
        f"{'|jitter| p99':>13} {'max':>8} {'behind at end':>14}"
    )
    for hz in (50.0, 100.0, 200.0):
        p = paced(hz, seconds)
        print(
            f"{hz:>6.0f} Hz {p.achieved_hz:>6.1f} Hz {1e3 / hz:>5.1f} ms {p.p50_ms:>10.2f} ms "
            f"{p.p99_ms:>5.2f} ms {p.p99_jitter_ms:>10.2f} ms {p.max_jitter_ms:>5.2f} ms "
            f"{p.behind_s * 1e3:>11.1f} ms"
        )
    q = paced_no_ack(200.0, seconds)
    print()
    print("200 Hz requested WITHOUT waiting for acks (raw frames; not a driver mode)")
    print(
        f"  sent {q.achieved_hz:.1f} Hz (|jitter| p99 {q.p99_jitter_ms:.2f} ms); acks arrived at "
        f"{q.acks_hz:.1f} Hz; the last ack came {q.ack_backlog_s:.2f} s after the last command"
    )
    print(
        "  The firmware serves one request per serial-task run: at 100 Hz every extra command "
        "waits in the\n  FC's receive buffer (the backlog grows 100 commands/s until the buffer "
        "overflows), so 200 Hz\n  cannot be delivered over MSP request/response; raise "
        "serial_update_rate_hz instead. The simulated\n  peer applies SET_MOTOR on arrival and "
        "only delays the reply, so it is kinder than real firmware here."
    )


if __name__ == "__main__":
    main()
