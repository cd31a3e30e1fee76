"""The parent's side of the motor-stop watchdog (``rig.watchdog``): start the process, wait
until it is ready, and end it with ``disarm`` (the FC acknowledged the stop) or ``hand_over``
(it did not: the watchdog reopens the port and stops the motors itself).

The MSP driver (``rig.fc.msp``) starts it before the first motor command; the process it runs,
``python -m thrustmap.rig.watchdog``, drives that same MSP driver. This module is the piece both
share (the ready/disarm lines on the pipe), so the driver never imports the process's module.
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from thrustmap.core.errors import SafetyError

log = logging.getLogger(__name__)

READY = b"ready\n"
DISARM = b"disarm\n"
#: how long the parent waits for the watchdog to report ready
START_TIMEOUT_S = 15.0
#: how long the watchdog keeps trying to reach the FC after its parent died
GIVE_UP_S = 30.0


def default_log_path() -> Path:
    """``$XDG_STATE_HOME/thrustmap/watchdog.log`` (``~/.local/state/...`` by default)."""
    base = os.environ.get("XDG_STATE_HOME") or os.path.join(
        os.path.expanduser("~"), ".local", "state"
    )
    return Path(base) / "thrustmap" / "watchdog.log"


@dataclass
class Watchdog:
    """The parent's handle on a running watchdog process."""

    process: subprocess.Popen[bytes]
    url: str
    log_path: Path | None

    @property
    def pid(self) -> int:
        return self.process.pid

    def disarm(self, wait_s: float = 2.0) -> None:
        """A clean end: the motors were stopped and the FC acknowledged it. The watchdog exits."""
        self._send(DISARM)
        self._close_pipe()
        try:
            self.process.wait(timeout=wait_s)
        except subprocess.TimeoutExpired:
            log.warning("watchdog (pid %d) did not exit after disarm", self.pid)

    def hand_over(self) -> None:
        """The stop was NOT confirmed: close our end without disarming. Call this after the
        port is closed; the watchdog then reopens it and stops the motors itself."""
        log.warning(
            "motor stop not confirmed: the watchdog (pid %d) now retries it on %s",
            self.pid,
            self.url,
        )
        self._close_pipe()

    def _send(self, line: bytes) -> None:
        pipe = self.process.stdin
        if pipe is None or pipe.closed:
            return
        try:
            pipe.write(line)
            pipe.flush()
        except OSError as exc:  # the watchdog died: nothing to disarm
            log.warning("watchdog (pid %d) is gone: %s", self.pid, exc)

    def _close_pipe(self) -> None:
        for pipe in (self.process.stdin, self.process.stdout):
            if pipe is not None and not pipe.closed:
                with contextlib.suppress(OSError):
                    pipe.close()


def start_watchdog(
    url: str,
    *,
    baudrate: int | None = None,
    log_path: str | os.PathLike[str] | None = None,
    give_up_s: float = GIVE_UP_S,
    timeout_s: float = START_TIMEOUT_S,
) -> Watchdog:
    """Start the watchdog for the MSP port at ``url`` and wait until it is ready.

    Raises :class:`SafetyError` when it cannot be started: a motor test must not begin
    without it."""
    path = Path(log_path) if log_path is not None else default_log_path()
    argv = [
        sys.executable,
        "-m",
        "thrustmap.rig.watchdog",
        "--url",
        url,
        "--parent-pid",
        str(os.getpid()),
        "--give-up-s",
        f"{give_up_s:g}",
        "--log",
        str(path),
    ]
    if baudrate is not None:
        argv += ["--baud", str(baudrate)]
    try:
        process = subprocess.Popen(
            argv,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=None,  # its outcome reaches the user's terminal while there is one
            close_fds=True,  # never hold the FC's port or socket: a dead parent must free it
            start_new_session=True,  # Ctrl-C and a closed terminal reach thrustmap, not it
        )
    except OSError as exc:
        raise SafetyError(f"cannot start the motor-stop watchdog: {exc}") from None
    watchdog = Watchdog(process, url, path)
    if not _await_ready(process, timeout_s):
        with contextlib.suppress(OSError):
            process.kill()
        process.wait()
        watchdog._close_pipe()
        raise SafetyError(
            f"the motor-stop watchdog did not start within {timeout_s:g} s "
            f"(exit code {process.returncode}); refusing to command a motor without it"
        )
    log.info("motor-stop watchdog running (pid %d) for %s; log %s", process.pid, url, path)
    return watchdog


def _await_ready(process: subprocess.Popen[bytes], timeout_s: float) -> bool:
    out = process.stdout
    assert out is not None
    deadline = time.monotonic() + timeout_s
    seen = b""
    while time.monotonic() < deadline:
        ready, _, _ = select.select([out], [], [], max(0.0, deadline - time.monotonic()))
        if not ready:
            break
        chunk = os.read(out.fileno(), 64)
        if not chunk:  # it exited
            return False
        seen += chunk
        if READY in seen:
            return True
    return False
