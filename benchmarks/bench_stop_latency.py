"""Stop latency on slow links: from the stop call to the verified stop, at 0/50/200/500 ms
injected per reply (issue 20), on simulated flight controllers and a simulated clock (exact and
repeatable; the real-firmware runs are in tests/test_betaflight_sitl.py).

MSP (sim://betaflight, a motor spinning at 1500): today's driver (reply waits learned from the
round trip, the stop sent at once and re-sent every 100 ms while its MSP_MOTOR check waits)
against the old fixed 100 ms wait with 2 retries (stop, wait for its reply, then read MSP_MOTOR).
MAVLink (sim://px4 motor test): today's driver (COMMAND_ACK wait learned from the link) against
the old fixed 0.5 s ACK wait. The MSP figure ends when the stop is verified (the driver then
re-enables arming, one more round trip not counted); the old MSP sequence ends at its verifying
read.

Prints, per latency, the time from the stop call until the stop was verified, or "failed".
Run: python benchmarks/bench_stop_latency.py
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the proxy: tests/support

from support.latency_proxy import LaggedPeer  # noqa: E402

import thrustmap.rig.devices.urls as urls
from thrustmap.core.clock import SimClock
from thrustmap.core.errors import ThrustmapError
from thrustmap.protocols.mavlink.link import MavlinkSerialLink
from thrustmap.protocols.msp.framing import MspCommand, encode_request
from thrustmap.protocols.msp.messages import SetArmingDisabled
from thrustmap.protocols.peer import create_peer
from thrustmap.protocols.urlhandlers.protocol_sim import SimSerial
from thrustmap.rig.fc.mavlink import open_mavlink_output
from thrustmap.rig.fc.msp import MspThrottleOutput
from thrustmap.rig.sim import peers

LATENCIES_S = (0.0, 0.05, 0.2, 0.5)


class ArmingWatch:
    """Passes bytes through; notes when the driver re-enables arming (it does so right after
    the stop was verified): that instant is the verified stop."""

    def __init__(self, inner: LaggedPeer) -> None:
        self.inner = inner
        self.arming_at: float | None = None
        self._frame = encode_request(
            MspCommand.SET_ARMING_DISABLED, SetArmingDisabled(False).encode()
        )

    def write(self, data: bytes, now_s: float) -> None:
        if self._frame in data and self.arming_at is None:
            self.arming_at = now_s
        self.inner.write(data, now_s)

    def read(self, now_s: float) -> bytes:
        return self.inner.read(now_s)


def msp_stop(delay_s: float, *, old: bool) -> float | None:
    peers.reset_benches()
    clock = SimClock(100.0)
    peer = create_peer("betaflight", {"bench": "bench", "protocol": "PWM"})
    watch = ArmingWatch(LaggedPeer(peer, delay_s))
    port = SimSerial(watch, clock, timeout=0)
    opts: dict[str, float | int] = {"timeout_s": 0.1, "retries": 2} if old else {}
    fc = MspThrottleOutput(port, clock, **opts)  # type: ignore[arg-type]
    try:
        fc.identify()
        fc.set_throttle({0: 1500.0})
        fc.motor_values()
    except ThrustmapError:
        return None  # the old driver cannot even start on this link
    t0 = clock.now_s()
    if old:  # the old sequence: stop (waiting for its reply), then MSP_MOTOR; three attempts
        for _ in range(3):
            try:
                fc.stop()
                if fc.verify_stopped():
                    return clock.now_s() - t0
            except ThrustmapError:
                continue
        return None
    ok = fc.stop_and_verify()
    return watch.arming_at - t0 if ok and watch.arming_at is not None else None


def mavlink_stop(delay_s: float, *, old: bool) -> float | None:
    peers.reset_benches()
    clock = SimClock(100.0)
    peer = create_peer("px4", {"bench": "bench", "motors": "1"})
    port = SimSerial(LaggedPeer(peer, delay_s), clock, timeout=0)
    opts = {"ack_timeout_s": 0.5} if old else {}
    try:
        out = open_mavlink_output(MavlinkSerialLink(port, clock), clock, **opts)  # type: ignore[arg-type]
        out.identify()
        out.set_throttle({0: float(out.throttle_scale.from_pct(10.0))})
        clock.sleep_s(1.0)
        out.keepalive()
    except ThrustmapError as exc:
        print(f"  (mavlink at {delay_s * 1000:.0f} ms: {exc})")  # noqa: T201
        return None
    t0 = clock.now_s()
    ok = out.stop_and_verify()
    return clock.now_s() - t0 if ok else None


def fmt(value: float | None) -> str:
    return "failed" if value is None else f"{value * 1000:7.0f} ms"


def main() -> None:
    urls.load_sim_peers()
    print("stop call -> verified stop, simulated clock")  # noqa: T201
    print(  # noqa: T201
        f"{'latency':>9} | {'MSP now':>10} | {'MSP old 100 ms':>14} | {'MAVLink now':>11} | "
        f"{'MAVLink old 0.5 s':>17}"
    )
    for delay_s in LATENCIES_S:
        row = (
            f"{delay_s * 1000:6.0f} ms | {fmt(msp_stop(delay_s, old=False)):>10} | "
            f"{fmt(msp_stop(delay_s, old=True)):>14} | "
            f"{fmt(mavlink_stop(delay_s, old=False)):>11} | "
            f"{fmt(mavlink_stop(delay_s, old=True)):>17}"
        )
        print(row)  # noqa: T201


if __name__ == "__main__":
    main()
