"""Loopback by default (issue 36, item 1) for the latency proxy: a test lists the sockets the
process really listens on (from the kernel's tables, /proc/net, matched to the process's own
file descriptors) while the proxy runs; none is outside loopback unless an address is named.
"""

from __future__ import annotations

import ipaddress
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from support.latency_proxy import LatencyProxy
from support.sockets import listening_sockets

PROC_NET = Path("/proc/net")
pytestmark = pytest.mark.skipif(
    not (PROC_NET / "tcp").exists(), reason="needs Linux /proc/net to list listening sockets"
)


def outside_loopback(sockets: list[tuple[str, str, int]]) -> list[tuple[str, str, int]]:
    return [s for s in sockets if not ipaddress.ip_address(s[1]).is_loopback]


def free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_the_lister_sees_a_socket_on_every_address() -> None:
    """The lister itself: a socket bound to 0.0.0.0 is reported as outside loopback."""
    with socket.socket() as s:
        s.bind(("0.0.0.0", 0))
        s.listen(1)
        port = s.getsockname()[1]
        assert ("tcp", "0.0.0.0", port) in outside_loopback(listening_sockets(os.getpid()))


def test_the_latency_proxy_listens_on_loopback_only() -> None:
    before = set(listening_sockets(os.getpid()))
    with LatencyProxy(("127.0.0.1", 9), 0.01) as proxy:
        opened = set(listening_sockets(os.getpid())) - before
        assert opened == {("tcp", "127.0.0.1", proxy.port)}
    assert set(listening_sockets(os.getpid())) - before == set()


def _proxy_process(*extra: str) -> tuple[subprocess.Popen[bytes], int]:
    port = free_tcp_port()
    tests = Path(__file__).resolve().parent  # support.latency_proxy lives in tests/support
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tests.parent), str(tests)]))
    child = subprocess.Popen(
        [sys.executable, "-m", "support.latency_proxy", "--listen", str(port)]
        + ["--to", "127.0.0.1:9", "--delay-ms", "10", *extra],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline and child.poll() is None:
        if any(p == port for _, _, p in listening_sockets(child.pid)):
            return child, port
        time.sleep(0.05)
    child.kill()
    child.wait(timeout=5)
    raise AssertionError("the latency proxy never listened")


@pytest.mark.parametrize(
    ("extra", "outside"), [((), False), (("--host", "0.0.0.0"), True)], ids=["default", "named"]
)
def test_python_m_latency_listens_on_loopback_unless_told(
    extra: tuple[str, ...], outside: bool
) -> None:
    child, port = _proxy_process(*extra)
    try:
        sockets = listening_sockets(child.pid)
    finally:
        child.terminate()
        _, err = child.communicate(timeout=10)
    assert ("tcp", "0.0.0.0" if outside else "127.0.0.1", port) in sockets
    assert bool(outside_loopback(sockets)) is outside
    assert (b"other hosts can reach the device" in err) is outside
