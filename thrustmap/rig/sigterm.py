"""Process-level safety: make SIGTERM unwind the stack like Ctrl-C so every ``finally`` and
context-manager exit (which stops the motors) runs."""

from __future__ import annotations

import logging
import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType

log = logging.getLogger(__name__)


class Terminated(KeyboardInterrupt):
    """Raised in the main thread when SIGTERM arrives (a KeyboardInterrupt, so nothing that
    catches ``Exception`` swallows it)."""


@contextmanager
def terminate_as_exception(
    *, stopping: str = "motors", sigint_always: bool = True
) -> Iterator[None]:
    """Within this block SIGTERM (and SIGHUP where it exists) raises ``Terminated``, and SIGINT
    raises ``KeyboardInterrupt`` even where the process inherited it ignored.

    A shell starts a background job (``thrustmap sweep … &``, ``nohup``, a script run from a
    non-interactive shell) with SIGINT ignored, and Python then installs no Ctrl-C handler: a
    SIGINT would leave the motor spinning to the end of its plan. While motors can be commanded,
    SIGINT always means stop; a handler the embedding program installed itself is kept. Work
    that commands no motor (``sigint_always=False``, e.g. the fleet) leaves an ignored SIGINT
    ignored, as the shell intends; ``stopping`` names what the warning says is stopped."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: FrameType | None) -> None:
        log.warning("signal %d received: stopping %s", signum, stopping)
        raise Terminated(f"signal {signum}")

    names = ["SIGTERM", "SIGHUP"]
    previous: dict[int, object] = {}
    for name in names:
        sig = getattr(signal, name, None)
        if sig is not None:
            previous[sig] = signal.signal(sig, handler)
    if sigint_always and not callable(signal.getsignal(signal.SIGINT)):  # no Python handler
        log.debug("SIGINT was not handled (a background job?): it will stop the motors")
        previous[signal.SIGINT] = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)  # type: ignore[arg-type]


@contextmanager
def interrupts_deferred() -> Iterator[list[int]]:
    """While the motors are being stopped, a second Ctrl-C or SIGTERM must not cut the stop
    short: signals are noted (the yielded list) and logged instead of raising."""
    if threading.current_thread() is not threading.main_thread():
        yield []
        return
    seen: list[int] = []

    def note(signum: int, frame: FrameType | None) -> None:
        seen.append(signum)
        log.warning(
            "signal %d received while stopping the motors: finishing the stop first", signum
        )

    previous: dict[int, object] = {}
    for name in ("SIGINT", "SIGTERM", "SIGHUP"):
        sig = getattr(signal, name, None)
        if sig is not None:
            previous[sig] = signal.signal(sig, note)
    try:
        yield seen
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)  # type: ignore[arg-type]
