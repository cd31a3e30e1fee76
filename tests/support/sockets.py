"""Which sockets a process really holds, from the kernel's tables (/proc/net, matched to the
process's own file descriptors): for tests that must know a port is bound (a readiness check,
not a sleep) or where it listens (loopback or not). Linux only."""

from __future__ import annotations

import ipaddress
import os
import socket
import time
from pathlib import Path

LISTEN = "0A"  # TCP_LISTEN in /proc/net/tcp
UNCONNECTED_UDP = "07"  # a bound UDP socket (TCP_CLOSE): it receives from anyone


def _address(hex_address: str, v6: bool) -> str:
    host_hex, _ = hex_address.split(":")
    raw = bytes.fromhex(host_hex)
    if v6:  # four host-order 32-bit words
        raw = b"".join(raw[i : i + 4][::-1] for i in range(0, 16, 4))
        return str(ipaddress.IPv6Address(raw))
    return str(ipaddress.IPv4Address(raw[::-1]))


def listening_sockets(pid: int) -> list[tuple[str, str, int]]:
    """(protocol, address, port) of every TCP socket listening and every UDP socket bound,
    unconnected, that process ``pid`` holds."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[len("socket:[") : -1])
    found = []
    for name, state in (("tcp", LISTEN), ("tcp6", LISTEN), ("udp", UNCONNECTED_UDP)):
        path = Path(f"/proc/{pid}/net/{name}")
        if not path.exists():
            continue
        for line in path.read_text().splitlines()[1:]:
            fields = line.split()
            if fields[3] != state or fields[9] not in inodes:
                continue
            port = int(fields[1].split(":")[1], 16)
            found.append((name, _address(fields[1], name.endswith("6")), port))
    return found


def wait_until_bound(pid: int, port: int, timeout_s: float = 60.0) -> bool:
    """True once process ``pid`` listens (TCP) or is bound (UDP) on ``port``; False when it
    exits or ``timeout_s`` passes first."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            if any(p == port for _, _, p in listening_sockets(pid)):
                return True
        except FileNotFoundError:  # the process is gone
            return False
        time.sleep(0.02)
    return False


def tcp_listener(host: str, port: int, backlog: int) -> socket.socket:
    """A TCP socket listening on (host, port), port 0 for any free one (``getsockname``)."""
    listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    listener.bind((host, port))
    listener.listen(backlog)
    return listener
