"""A motor-stop watchdog: a small process that stops the motors if thrustmap dies first.

Betaflight (and every MSP firmware) keeps the last SET_MOTOR value forever: there is no timeout
in the firmware. thrustmap stops and verifies on every way out it can see (end, exception,
Ctrl-C, SIGTERM, SIGHUP), but not when it is killed outright (SIGKILL, the out-of-memory killer,
a crash of the interpreter). So, before the first motor command, the MSP driver starts this
watchdog as a separate process:

- it runs in its own session (a closed terminal or a Ctrl-C reaches thrustmap, not it) and
  ignores SIGINT and SIGHUP;
- it watches its parent through a pipe (the parent holds the write end: EOF means the parent
  is gone, however it died) and by checking every ``poll_s`` that the parent still exists;
- a clean exit disarms it (``disarm`` on the pipe, sent only after a stop the FC acknowledged);
- otherwise, once the parent is gone, it reopens the same port (for a TCP SITL it waits for
  the port to be free: the firmware serves one MSP connection at a time), sends 1000 for all 8
  motors, verifies with MSP_MOTOR, re-enables arming as the driver would, and logs the outcome
  to stderr and to its log file.

It never sends anything that can start a motor: SET_MOTOR with the stop value for every motor,
MSP_MOTOR / MOTOR_CONFIG reads, and SET_ARMING_DISABLED 0 after a verified stop.

Run as ``python -m thrustmap.rig.watchdog --url URL --parent-pid PID [--baud N] [--log FILE]``;
:func:`~thrustmap.rig.watchdog_handle.start_watchdog` does that and returns a
:class:`~thrustmap.rig.watchdog_handle.Watchdog` handle. The handle lives in
``rig.watchdog_handle``, below both this process and the MSP driver that starts it.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import select
import signal
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import IO

from thrustmap.rig.watchdog_handle import DISARM, GIVE_UP_S, READY

__all__ = [
    "MAX_LOG_BYTES",
    "main",
    "stop_motors",
    "wait_for_parent",
]

log = logging.getLogger(__name__)

#: a log file over this size is moved aside (``.old``) before the watchdog appends to it
MAX_LOG_BYTES = 1_000_000


# --------------------------------------------------------------------------- the process


def _parent_alive(parent_pid: int) -> bool:
    if os.getppid() != parent_pid:  # re-parented: the parent is gone
        return False
    try:
        os.kill(parent_pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def wait_for_parent(stdin: IO[bytes], parent_pid: int, poll_s: float = 0.5) -> bool:
    """Block until the parent disarms us (True) or goes away without it (False)."""
    buffered = b""
    fd = stdin.fileno()
    while True:
        ready, _, _ = select.select([fd], [], [], poll_s)
        if ready:
            chunk = os.read(fd, 256)
            if not chunk:
                return DISARM.strip() in buffered.split()
            buffered = (buffered + chunk)[-256:]
            if DISARM.strip() in buffered.split():
                return True
        elif not _parent_alive(parent_pid):
            return False


def stop_motors(url: str, *, baudrate: int | None, give_up_s: float) -> bool:
    """Reopen ``url`` and stop every motor; True once the FC confirmed it.

    Keeps trying (the port may still be held by the dying parent, or a TCP SITL may still be
    serving the old connection) until ``give_up_s``."""
    from thrustmap.core.clock import MonotonicClock
    from thrustmap.core.errors import ThrustmapError
    from thrustmap.protocols.transport import open_transport
    from thrustmap.rig.fc.msp import MspThrottleOutput

    clock = MonotonicClock()
    deadline = clock.now_s() + give_up_s
    attempt = 0
    acknowledged = False
    while True:
        attempt += 1
        try:
            kwargs: dict[str, object] = {"timeout": 0}
            if baudrate is not None:
                kwargs["baudrate"] = baudrate
            port = open_transport(url, **kwargs)
        except Exception as exc:  # busy, refused, unplugged: try again
            log.info("attempt %d: cannot open %s yet: %s", attempt, url, exc)
        else:
            output = MspThrottleOutput(port, clock, retries=2, watchdog=False)
            try:
                outcome = output.watchdog_stop()
                if outcome == "verified":
                    log.warning("motors stopped on %s (verified by MSP_MOTOR)", url)
                    return True
                if outcome == "unverifiable":
                    acknowledged = True
                    log.warning(
                        "stop sent to %s and acknowledged, but it cannot be verified: %s",
                        url,
                        output.stop_unverifiable,
                    )
                    return False
                log.warning("attempt %d: stop sent, not yet confirmed", attempt)
            except ThrustmapError as exc:
                log.info("attempt %d: %s", attempt, exc)
            except OSError as exc:
                log.info("attempt %d: link error: %s", attempt, exc)
            finally:
                with contextlib.suppress(Exception):
                    port.close()
        if clock.now_s() >= deadline:
            if not acknowledged:
                log.critical(
                    "COULD NOT STOP THE MOTORS on %s after %.0f s - disconnect the battery now",
                    url,
                    give_up_s,
                )
            return False
        clock.sleep_s(0.2)


def _setup_logging(log_path: str | None) -> None:
    logging.raiseExceptions = False  # a closed terminal must not stop the stop
    root = logging.getLogger()
    root.setLevel(logging.INFO)
    fmt = logging.Formatter("%(asctime)s thrustmap-watchdog[%(process)d] %(levelname)s %(message)s")
    stderr = logging.StreamHandler(sys.stderr)
    stderr.setLevel(logging.WARNING)
    stderr.setFormatter(fmt)
    root.addHandler(stderr)
    if log_path:
        try:
            Path(log_path).parent.mkdir(parents=True, exist_ok=True)
            path = Path(log_path)
            if path.exists() and path.stat().st_size > MAX_LOG_BYTES:
                os.replace(path, f"{path}.old")  # bounded: this file and the one before
            handler = logging.FileHandler(log_path, encoding="utf-8")
        except OSError as exc:
            log.warning("cannot write the watchdog log %s: %s", log_path, exc)
        else:
            handler.setFormatter(fmt)
            root.addHandler(handler)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m thrustmap.rig.watchdog")
    parser.add_argument("--url", required=True)
    parser.add_argument("--parent-pid", type=int, required=True)
    parser.add_argument("--baud", type=int, default=None)
    parser.add_argument("--log", default=None)
    parser.add_argument("--give-up-s", type=float, default=GIVE_UP_S)
    args = parser.parse_args(argv)
    for name in ("SIGINT", "SIGHUP", "SIGPIPE"):
        sig = getattr(signal, name, None)
        if sig is not None:
            signal.signal(sig, signal.SIG_IGN)
    _setup_logging(args.log)
    # Import what the stop needs before saying ready: a broken install fails here, not later.
    import thrustmap.protocols.transport  # noqa: F401
    import thrustmap.rig.fc.msp  # noqa: F401

    try:
        os.write(sys.stdout.fileno(), READY)
    except OSError:
        return 1  # the parent is already gone and never learned we exist
    log.info("armed for %s (parent pid %d)", args.url, args.parent_pid)
    if wait_for_parent(sys.stdin.buffer, args.parent_pid):
        log.info("disarmed: the parent stopped the motors itself")
        return 0
    log.warning(
        "thrustmap (pid %d) ended without a confirmed motor stop: stopping the motors on %s",
        args.parent_pid,
        args.url,
    )
    return 0 if stop_motors(args.url, baudrate=args.baud, give_up_s=args.give_up_s) else 3


if __name__ == "__main__":
    sys.exit(main())
