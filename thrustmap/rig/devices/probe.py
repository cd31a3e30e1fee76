"""``thrustmap probe``: identify what is at a URL and take a short live reading.

An FC is opened as a throttle output (its exit commands stop and verifies it, as always) but no
motor is commanded; a stand is read for a second or so.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from thrustmap.core.clock import Clock
from thrustmap.core.errors import ConfigError, SafetyError, ThrustmapError
from thrustmap.rig.devices.declaration import Detection
from thrustmap.rig.devices.detect import resolve
from thrustmap.rig.devices.registry import driver
from thrustmap.rig.interfaces import DeviceIdentity, StandSample, Telemetry


@dataclass
class StandSummary:
    samples: int
    duration_s: float
    rate_hz: float | None
    means: dict[str, float]  # field -> mean over the window (fields the stand reports)
    bad_lines: int = 0


@dataclass
class ProbeReport:
    url: str
    detection: Detection
    identity: DeviceIdentity | None = None
    throttle_scale: str = ""
    telemetry: Telemetry | None = None
    motor_values: tuple[int, ...] | None = None
    stand: StandSummary | None = None
    warnings: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, object]:
        out: dict[str, object] = {
            "url": self.url,
            "kind": self.detection.kind,
            "firmware": self.detection.firmware,
            "evidence": self.detection.evidence,
            "identity": None if self.identity is None else self.identity.to_dict(),
            "throttle_scale": self.throttle_scale,
            "warnings": list(self.warnings),
        }
        if self.telemetry is not None:
            t = self.telemetry
            out["telemetry"] = {
                "voltage_v": t.voltage_v,
                "current_a": t.current_a,
                "rpm": None if t.rpm is None else list(t.rpm),
                "temperature_c": None if t.temperature_c is None else list(t.temperature_c),
            }
        if self.motor_values is not None:
            out["motor_values"] = list(self.motor_values)
        if self.stand is not None:
            out["stand"] = {
                "samples": self.stand.samples,
                "duration_s": self.stand.duration_s,
                "rate_hz": self.stand.rate_hz,
                "means": dict(self.stand.means),
                "bad_lines": self.stand.bad_lines,
            }
        return out


def summarize_samples(samples: Sequence[StandSample], duration_s: float) -> StandSummary:
    means: dict[str, float] = {}
    for name in ("thrust_n", "torque_nm", "voltage_v", "current_a", "rpm", "temperature_c"):
        values = [getattr(s, name) for s in samples if getattr(s, name) is not None]
        if values:
            means[name] = math.fsum(values) / len(values)
    rate = None
    if len(samples) >= 2 and samples[-1].time_s > samples[0].time_s:
        rate = (len(samples) - 1) / (samples[-1].time_s - samples[0].time_s)
    return StandSummary(len(samples), duration_s, rate, means)


@dataclass(frozen=True)
class StandOptions:
    """How to read a stand: its calibration file, a line-stand preset or spec file."""

    calibration: str | None = None
    line_preset: str | None = None
    line_spec_file: str | None = None


def probe_device(
    url: str,
    clock: Clock,
    *,
    kind: str | None = None,
    baudrate: int | None = None,
    stand: StandOptions | None = None,
    seconds: float = 1.0,
    signing_key: Any = None,
) -> ProbeReport:
    """Identify what is at ``url`` and take a short live reading. An FC is opened as a throttle
    output (its exit commands stop and verifies it, as always) but no motor is commanded."""
    found = resolve(url, clock, kind, baudrate)
    report = ProbeReport(url, found)
    try:
        return _probe(report, url, clock, kind, baudrate, stand or StandOptions(), seconds,
                      signing_key)  # fmt: skip
    finally:  # say how this kind's protocol was checked (a real device, an official client...)
        checked = driver(found.kind).verified
        spec_checked = report.identity.details.get("verified") if report.identity else None
        checked = spec_checked or checked
        if report.identity is not None and checked:
            details = {**report.identity.details, "protocol_checked": checked}
            details.pop("verified", None)
            report.identity = replace(report.identity, details=details)


def _probe(
    report: ProbeReport,
    url: str,
    clock: Clock,
    kind: str | None,
    baudrate: int | None,
    options: StandOptions,
    seconds: float,
    signing_key: Any,
) -> ProbeReport:
    from thrustmap.rig.devices.opening import open_stand, open_throttle_output
    from thrustmap.rig.stand.line import LineStand

    found = report.detection
    if signing_key is not None and found.kind != "mavlink":
        if not getattr(signing_key, "from_environment", False):
            raise ConfigError(
                f"--signing-key is for MAVLink vehicles (PX4, ArduPilot); {url} is {found.kind}"
            )
        signing_key = None  # the environment's key is for MAVLink devices only
    if driver(found.kind).role == "fc":
        output = open_throttle_output(
            url, clock, kind=kind or found.kind, baudrate=baudrate, signing_key=signing_key
        )
        with output:
            try:
                report.identity = output.identify()
            except SafetyError as exc:
                report.warnings.append(str(exc))
            report.throttle_scale = output.throttle_scale.name
            try:
                report.telemetry = output.read_telemetry()
            except ThrustmapError as exc:
                report.warnings.append(f"no telemetry: {exc}")
            motor_values = getattr(output, "motor_values", None)
            if callable(motor_values):
                try:
                    report.motor_values = tuple(int(v) for v in motor_values())
                    if not any(report.motor_values):  # 0 = "no information", not "stopped"
                        report.warnings.append(
                            "MSP_MOTOR reads 0 for every motor: this FC reports no motor "
                            "values, so a motor stop cannot be verified on it"
                        )
                except ThrustmapError as exc:
                    report.warnings.append(f"no motor values: {exc}")
        return report
    if (
        found.kind == "line-stand"
        and found.line_preset is None
        and options.line_preset is None
        and options.line_spec_file is None
    ):
        raise ConfigError(
            f"{url} prints text lines no line-stand preset knows ({found.evidence}); "
            "pass --line-preset or describe it with --line-spec"
        )
    stand = open_stand(
        url,
        clock,
        kind=found.kind,
        calibration=options.calibration,
        # the preset the port's own lines identified (opening again by kind does not sniff)
        line_preset=options.line_preset
        or (found.line_preset if options.line_spec_file is None else None),
        line_spec_file=options.line_spec_file,
        baudrate=baudrate,
    )
    with stand:
        report.identity = stand.identify()
        start = clock.now_s()
        samples: list[StandSample] = []
        while True:
            samples += stand.read_samples()
            if clock.now_s() - start >= seconds:
                break
            clock.sleep_s(0.02)
        report.stand = summarize_samples(samples, clock.now_s() - start)
        if isinstance(stand, LineStand):
            report.stand.bad_lines = stand.error_count
            report.identity = stand.identify()
            if stand.spec.sequence_start is not None and not samples:
                report.warnings.append(
                    f"{stand.spec.name} prints only during its own sweep, started by "
                    f"{stand.spec.sequence_start.strip()!r} (probe never sends it): "
                    "thrustmap stand run"
                )
    return report
