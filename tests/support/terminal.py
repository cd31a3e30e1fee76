"""A command on a pseudo-terminal of a given width, as a user's terminal runs it."""

from __future__ import annotations

import fcntl
import os
import re
import select
import shlex
import struct
import subprocess
import sys
import termios
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
ANSI = re.compile(r"\x1b(\[[0-?]*[ -/]*[@-~]|\][^\x07]*\x07|[()][0-9A-Za-z]|[=>78])")


def run_in_terminal(
    command: str, cwd: Path, cols: int = 80, timeout_s: float = 180
) -> tuple[int, str]:
    """``command`` (a shell line; ``thrustmap`` is this checkout's CLI) on a cols-wide pty.

    Returns the exit code and every line the terminal received, escape sequences removed and
    each carriage-return segment a line of its own (a live panel redraws with them).
    """
    master, slave = os.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 40, cols, 0, 0))
    # COLUMNS as the issue asks; the CLI itself reads the terminal's size, which is the same
    env = {**os.environ, "PYTHONPATH": str(ROOT), "TERM": "xterm-256color", "COLUMNS": str(cols)}
    env.pop("LINES", None)
    shell = f'thrustmap() {{ {shlex.quote(sys.executable)} -m thrustmap "$@"; }}; {command}'
    proc = subprocess.Popen(
        ["bash", "-c", shell], cwd=cwd, stdin=slave, stdout=slave, stderr=slave, env=env,
        start_new_session=True,
    )  # fmt: skip
    os.close(slave)
    chunks: list[bytes] = []
    deadline = time.monotonic() + timeout_s
    try:
        while time.monotonic() < deadline:
            ready, _, _ = select.select([master], [], [], 0.2)
            if ready:
                try:
                    data = os.read(master, 65536)
                except OSError:  # the child closed the terminal
                    break
                if not data:
                    break
                chunks.append(data)
            elif proc.poll() is not None:
                break
        code = proc.wait(timeout=max(1.0, deadline - time.monotonic()))
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        os.close(master)
    text = ANSI.sub("", b"".join(chunks).decode("utf-8", "replace"))
    lines = [seg for line in text.split("\n") for seg in line.split("\r")]
    return code, "\n".join(lines)


@dataclass(frozen=True)
class DemoRun:
    """One ``thrustmap demo`` as the README's set-up step runs it: in ``folder``, its results in
    ``folder / "thrustmap-demo"``, on an 80-column terminal; its exit code and every line the
    terminal received."""

    folder: Path
    code: int
    output: str
