"""The one identity check for inputs that are pooled: nothing is counted twice.

Every place that pools inputs (stand logs in ``fit``/``compare``/``evaluate``/``report``, Df
files and their flights in ``gamma fit`` and ``fleet gamma``, flight logs in ``flightlog
extract``) describes each input as an :class:`Identity` and calls :func:`refuse_repeats`. Two
inputs are the same when their content hashes (sha256) agree and, for flights, when their time
spans in that log overlap: the same flight extracted twice (at 1.5 kg and at 1.4 kg, say) is
still one flight. A repeat is refused naming both, so ``fit a.csv a.csv`` never doubles n and
narrows the interval, and a flight never escapes the mixed-mass refusal by appearing twice.

Light on imports: hashing and comparing only.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from thrustmap.core.errors import DataFormatError


@dataclass(frozen=True)
class Identity:
    """One pooled input: how the user named it, its content hash and, for a flight, its time
    span (s, on the log's own clock)."""

    name: str
    sha256: str
    span_s: tuple[float, float] | None = None

    def same_as(self, other: Identity) -> bool:
        if not self.sha256 or self.sha256 != other.sha256:
            return False
        if self.span_s is None or other.span_s is None:
            return True
        return self.span_s[0] <= other.span_s[1] and other.span_s[0] <= self.span_s[1]


def file_sha256(path: str | Path, chunk: int = 1 << 20) -> str:
    """The sha256 of a file's bytes, read in chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(chunk), b""):
            h.update(block)
    return h.hexdigest()


def refuse_repeats(items: Iterable[Identity], what: str) -> None:
    """Refuse when two of ``items`` are the same input (content, and span for flights), naming
    both: pooled, the repeat would count its data twice."""
    seen: dict[str, list[Identity]] = {}  # by hash: a fleet's thousands of flights, in time
    for item in items:
        for first in seen.get(item.sha256, []):
            if item.same_as(first):
                raise DataFormatError(
                    describe_repeat(first, item, what) + ": pooled, its data would count "
                    "twice" + (" (and two masses for one flight cannot both be right)"
                               if first.span_s is not None else "") + "; give it once"
                )  # fmt: skip
        seen.setdefault(item.sha256, []).append(item)


def describe_repeat(first: Identity, second: Identity, what: str) -> str:
    """``a and b are the same <what> (sha256 …)``: what a refusal, or a pool that keeps one of
    them (the fleet names its Df files by content), says."""
    short = first.sha256[:12]
    if first.span_s is not None and second.span_s is not None:
        a, b = first.span_s, second.span_s
        return (
            f"{first.name} and {second.name} are the same {what} (log sha256 {short}…, "
            f"{a[0]:.1f}..{a[1]:.1f} s and {b[0]:.1f}..{b[1]:.1f} s), extracted twice"
        )
    same = "the same file" if first.name == second.name else "the same content"
    return f"{first.name} and {second.name} are {same} (sha256 {short}…): each {what} counts once"
