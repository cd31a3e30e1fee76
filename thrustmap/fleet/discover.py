"""Which files a fleet run reads: folders (recursively), globs and plain files."""

from __future__ import annotations

import glob
import os
import stat
from collections.abc import Iterable
from pathlib import Path

from thrustmap.core.errors import ConfigError

#: suffixes a folder is searched for (lower case); a file or glob named explicitly is always read
LOG_SUFFIXES = frozenset({".ulg", ".bin", ".tlog", ".bbl", ".bfl", ".db3", ".mcap", ".csv"})


def _regular(path: Path) -> bool:
    """A regular file (a FIFO, socket or device named like a log would block or never end)."""
    try:
        return stat.S_ISREG(path.stat().st_mode)
    except OSError:
        return False


def _walk(folder: Path) -> Iterable[Path]:
    for root, dirs, files in os.walk(folder, followlinks=False):
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        for name in sorted(files):
            p = Path(root) / name
            if p.suffix.lower() in LOG_SUFFIXES and not name.startswith(".") and _regular(p):
                yield p


def discover(
    sources: Iterable[str | os.PathLike[str]], *, exclude: Path | None = None
) -> list[Path]:
    """Every log named by ``sources``, each once (absolute, sorted by path).

    A folder contributes the files under it with a flight-log suffix (hidden ones and anything
    under ``exclude``, the fleet's own output folder, skipped); a glob its matches; a file itself.
    A source that names nothing is refused (a typo must not look like an empty fleet). Only
    regular files are taken from folders and globs; a FIFO or device named explicitly is listed
    and refused by its task, unread.
    """
    found: set[Path] = set()
    skip = exclude.resolve() if exclude is not None else None
    for src in sources:
        text = os.fspath(src)
        p = Path(text)
        if p.is_dir():
            hits = list(_walk(p))
        elif p.exists() and not glob.has_magic(text):
            hits = [p]  # named explicitly: read, or refused with its reason if not a file
        elif glob.has_magic(text):
            hits = []
            for m in sorted(glob.glob(text, recursive=True)):
                mp = Path(m)
                hits.extend(_walk(mp) if mp.is_dir() else [mp] if _regular(mp) else [])
            if not hits:
                raise ConfigError("the pattern matches no file", file=text)
        else:
            raise ConfigError("no such file or folder", file=text)
        for h in hits:
            a = h.absolute()
            if skip is not None and a.resolve().is_relative_to(skip):
                continue
            found.add(a)
    return sorted(found)
