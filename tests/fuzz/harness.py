"""Fuzz harness: mutate our own fixtures and run a reader on each, isolated and bounded.

Every input runs in a forked child with an address-space limit (``resource.setrlimit``) and a
per-input alarm, so a reader that hangs or allocates without bound is caught as a failure instead
of taking the test run down. The only acceptable outcomes are a normal return or a
:class:`~thrustmap.core.errors.ThrustmapError`; anything else (another exception, a timeout, running
out of the memory limit, a crash) is reported with the mutation that caused it.
"""

from __future__ import annotations

import os
import pickle
import random
import resource
import signal
import struct
import sys
import time
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: address-space ceiling of a fuzz child, above what the process already maps (bytes)
MEMORY_HEADROOM = 1024 * 1024 * 1024


@dataclass(frozen=True)
class Mutant:
    name: str  # how it was made, e.g. "bitflip(17)@seed3"
    data: bytes


@dataclass(frozen=True)
class Outcome:
    name: str
    kind: str  # "ok" | "typed" | "error" | "timeout" | "memory" | "crash"
    detail: str
    seconds: float


# -- mutations ------------------------------------------------------------------------------------


def bit_flips(data: bytes, rng: random.Random, count: int) -> bytes:
    buf = bytearray(data)
    for _ in range(count):
        i = rng.randrange(len(buf))
        buf[i] ^= 1 << rng.randrange(8)
    return bytes(buf)


def truncate(data: bytes, rng: random.Random) -> bytes:
    return data[: rng.randrange(len(data))]


def splice(data: bytes, rng: random.Random) -> bytes:
    """A chunk of the file copied over another place (a torn or duplicated write)."""
    n = len(data)
    a, b = sorted(rng.sample(range(n), 2))
    at = rng.randrange(n)
    return data[:at] + data[a:b] + data[at:]


def cut_out(data: bytes, rng: random.Random) -> bytes:
    n = len(data)
    a, b = sorted(rng.sample(range(n), 2))
    return data[:a] + data[b:]


def interesting_values(data: bytes, rng: random.Random, count: int) -> bytes:
    """Overwrite aligned 1/2/4/8-byte words with boundary values (lengths, counts, sizes)."""
    buf = bytearray(data)
    values = [0, 0xFF, 0x7F, 0x80, 0xFFFF, 0x7FFF, 0xFFFFFFFF, 0x7FFFFFFF, 0x80000000]
    for _ in range(count):
        width = rng.choice((1, 2, 4, 8))
        i = rng.randrange(max(1, len(buf) - width))
        value = rng.choice(values) & ((1 << (8 * width)) - 1)
        buf[i : i + width] = value.to_bytes(width, "little")
    return bytes(buf)


def text_mutations(data: bytes, rng: random.Random) -> bytes:
    """Text-level damage for CSV/JSON: a huge number, a non-number, an odd separator, a long cell,
    a blank line, a non-UTF-8 byte, a duplicated or dropped separator."""
    lines = data.split(b"\n")
    i = rng.randrange(len(lines))
    line = lines[i]
    choice = rng.randrange(9)
    if choice == 0:
        lines[i] = line.replace(b",", b",9" * 1 + b"9" * 400, 1)
    elif choice == 1:
        lines[i] = line.replace(b",", b",abc", 1)
    elif choice == 2:
        lines[i] = line.replace(b",", b";")
    elif choice == 3:
        lines[i] = line + b"," + b"x" * 140_000
    elif choice == 4:
        lines.insert(i, b"")
    elif choice == 5:
        lines[i] = line + b"\xff\xfe"
    elif choice == 6:
        lines[i] = line.replace(b",", b",,", 1)
    elif choice == 7:
        lines[i] = line.rsplit(b",", 1)[0]
    else:
        lines[i] = line.replace(b".", b"e999", 1)
    return b"\n".join(lines)


def mutants(data: bytes, seed: int, count: int, *, text: bool = False) -> Iterator[Mutant]:
    """``count`` mutants of ``data``, reproducible from ``seed``."""
    rng = random.Random(seed)
    for k in range(count):
        op = rng.randrange(7 if text else 6)
        tag = f"seed{seed}#{k}"
        if op == 0:
            flips = rng.choice((1, 4, 17, 64))
            yield Mutant(f"bitflip({flips})@{tag}", bit_flips(data, rng, flips))
        elif op == 1:
            yield Mutant(f"truncate@{tag}", truncate(data, rng))
        elif op == 2:
            yield Mutant(f"splice@{tag}", splice(data, rng))
        elif op == 3:
            yield Mutant(f"cut@{tag}", cut_out(data, rng))
        elif op == 4:
            yield Mutant(f"values@{tag}", interesting_values(data, rng, rng.choice((1, 3, 8))))
        elif op == 5:
            yield Mutant(f"bitflip(2)@{tag}", bit_flips(data, rng, 2))
        else:
            yield Mutant(f"text@{tag}", text_mutations(data, rng))


# -- bounded, isolated execution ------------------------------------------------------------------


class _Timeout(BaseException):
    pass


def _on_alarm(signum: int, frame: Any) -> None:
    raise _Timeout()


def _classify(exc: BaseException) -> tuple[str, str]:
    from thrustmap.core.errors import ThrustmapError

    if isinstance(exc, ThrustmapError):
        text = str(exc)
        if "\n" in text:
            return "error", f"multi-line ThrustmapError: {text[:300]!r}"
        return "typed", text[:200]
    if isinstance(exc, _Timeout):
        return "timeout", "per-input time limit"
    if isinstance(exc, MemoryError):
        return "memory", "memory limit"
    tb = traceback.format_exception(type(exc), exc, exc.__traceback__)
    return "error", f"{type(exc).__name__}: {str(exc)[:200]} | {''.join(tb[-3:])[-600:]}"


def _vm_bytes() -> int:
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[0]) * resource.getpagesize()
    except OSError:  # pragma: no cover - not Linux
        return 0


def run_bounded(
    fn: Callable[[Path], Any],
    inputs: list[Mutant],
    workdir: Path,
    *,
    suffix: str,
    timeout_s: float = 10.0,
    memory_bytes: int = MEMORY_HEADROOM,
) -> list[Outcome]:
    """Run ``fn(path)`` on every input in one forked child with limits; outcomes in order.

    A child that dies (hard crash, memory limit hit outside Python) is restarted after the input
    it died on, which is recorded as "crash".
    """
    outcomes: list[Outcome] = []
    todo = list(inputs)
    while todo:
        read_fd, write_fd = os.pipe()
        pid = os.fork()
        if pid == 0:  # child
            os.close(read_fd)
            code = 0
            try:
                _child(fn, todo, workdir, suffix, timeout_s, memory_bytes, write_fd)
            except BaseException:  # pragma: no cover - reported by the parent as a crash
                code = 3
            finally:
                os._exit(code)
        os.close(write_fd)
        got: list[Outcome] = []
        with os.fdopen(read_fd, "rb") as pipe:
            while True:
                head = pipe.read(4)
                if len(head) < 4:
                    break
                (size,) = struct.unpack("<I", head)
                got.append(pickle.loads(pipe.read(size)))
        os.waitpid(pid, 0)
        outcomes.extend(got)
        todo = todo[len(got) :]
        if todo:  # the child died on todo[0]
            outcomes.append(Outcome(todo[0].name, "crash", "child process died", 0.0))
            todo = todo[1:]
    return outcomes


def _child(
    fn: Callable[[Path], Any],
    todo: list[Mutant],
    workdir: Path,
    suffix: str,
    timeout_s: float,
    memory_bytes: int,
    write_fd: int,
) -> None:
    limit = _vm_bytes() + memory_bytes
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    signal.signal(signal.SIGALRM, _on_alarm)
    sys.setrecursionlimit(max(sys.getrecursionlimit(), 1000))
    with os.fdopen(write_fd, "wb") as pipe:
        for k, m in enumerate(todo):
            path = workdir / f"fuzz{os.getpid()}_{k}{suffix}"
            path.write_bytes(m.data)
            t0 = time.monotonic()
            try:
                signal.setitimer(signal.ITIMER_REAL, timeout_s)
                try:
                    fn(path)
                finally:
                    signal.setitimer(signal.ITIMER_REAL, 0)
                kind, detail = "ok", ""
            except BaseException as exc:  # noqa: BLE001 - classified below
                kind, detail = _classify(exc)
            finally:
                path.unlink(missing_ok=True)
            out = Outcome(m.name, kind, detail, time.monotonic() - t0)
            blob = pickle.dumps(out)
            pipe.write(struct.pack("<I", len(blob)) + blob)
            pipe.flush()


def failures(outcomes: list[Outcome]) -> list[Outcome]:
    return [o for o in outcomes if o.kind not in ("ok", "typed")]


def describe(outcomes: list[Outcome], limit: int = 8) -> str:
    bad = failures(outcomes)
    lines = [f"{len(bad)} of {len(outcomes)} inputs failed:"]
    lines += [f"  {o.name}: {o.kind} {o.detail} ({o.seconds:.1f} s)" for o in bad[:limit]]
    return "\n".join(lines)
