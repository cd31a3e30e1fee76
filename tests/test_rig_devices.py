"""The driver registry: one declaration makes a new device detectable, probe-able and openable
(detection, --kind, open_stand, stand_esc_output all iterate the registry)."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping

import pytest

import thrustmap.rig.devices.detect as detect
import thrustmap.rig.devices.opening as opening
from thrustmap.core.clock import SimClock
from thrustmap.core.errors import ConfigError
from thrustmap.rig.devices import registry
from thrustmap.rig.devices.declaration import Detection, Driver, OpenRequest
from thrustmap.rig.interfaces import DeviceIdentity, Stand, StandSample


class FakeStand(Stand):
    def __init__(self, url: str) -> None:
        self.url = url
        self.closed = False

    def identify(self) -> DeviceIdentity:
        return DeviceIdentity(kind="acme-stand", details={"url": self.url})

    def read_samples(self) -> list[StandSample]:
        return [StandSample(0.0, 1.25)]

    def tare(self, service: Callable[[], None] | None = None) -> None:
        pass

    def close(self) -> None:
        self.closed = True


def _sim(name: str, options: Mapping[str, str]) -> Detection | None:
    return Detection("acme-stand", evidence="sim") if name == "acme" else None


def _classify(data: bytes, lines: list[str]) -> Detection | None:
    return Detection("acme-stand", evidence="ACME banner") if "ACME v1" in lines else None


ACME = Driver(
    kind="acme-stand",
    role="stand",
    description="ACME stand",
    default_baud=9600,
    aliases={"acme": None, "acme-stand": None},
    sim_detect=_sim,
    classify=_classify,
    open_stand=lambda req: FakeStand(req.url),
)


@pytest.fixture
def acme() -> Iterator[Driver]:
    registry.register(ACME)
    yield ACME
    registry.unregister(ACME.kind)


def test_one_declaration_makes_a_stand_known_everywhere(acme: Driver) -> None:
    assert registry.normalize_kind("ACME") == ("acme-stand", None)
    assert "acme-stand" in registry.kinds("stand") and "acme" in registry.kind_aliases()
    found = detect.detect_from_url("sim://acme")
    assert found is not None and found.kind == "acme-stand"
    found = detect.classify_bytes(b"noise\r\nACME v1\r\n")
    assert found is not None and found.evidence == "ACME banner"
    stand = opening.open_stand("/dev/ttyACME", SimClock(), kind="acme")
    assert isinstance(stand, FakeStand) and stand.identify().details["url"] == "/dev/ttyACME"
    with pytest.raises(ConfigError, match="cannot drive an ESC"):
        opening.stand_esc_output(stand)


def test_registry_refuses_a_duplicate_and_unknown_kinds(acme: Driver) -> None:
    with pytest.raises(ValueError, match="acme-stand"):
        registry.register(ACME)
    with pytest.raises(ConfigError, match="unknown device kind 'nope'"):
        registry.normalize_kind("nope")
    with pytest.raises(ConfigError, match="no driver"):
        registry.driver("nope")


def test_builtin_drivers_in_detection_order() -> None:
    assert registry.kinds() == ("msp", "mavlink", "tyto-1585", "line-stand", "flightstand")
    assert registry.kinds("fc") == ("msp", "mavlink")
    req = OpenRequest("x", SimClock())
    assert req.wait_s == 3.0 and dict(req.opts) == {}


def test_mavlink_factory_opens_a_sim_url_in_a_fresh_process() -> None:
    """The rig's MAVLink factory (``rig.fc.mavlink.open_mavlink_output``) loads the simulator's
    peers for a sim:// URL: nothing imported before it (another test, the CLI) has to have
    registered them."""
    import subprocess
    import sys

    code = (
        "from thrustmap.core.clock import SimClock\n"
        "from thrustmap.rig.fc.mavlink import open_mavlink_output\n"
        "with open_mavlink_output('sim://px4?motors=4', SimClock()) as out:\n"
        "    print(out.identify().kind)\n"
        "print(out.last_stop_verified)\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["px4", "True"]
