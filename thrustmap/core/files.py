"""Writing files safely: atomic replacement, no symlink following, never over an input.

Every file thrustmap writes goes through here:

- :func:`atomic_write_text` / :func:`atomic_write_bytes` write to a temporary file created
  securely in the target's own folder (as ``tempfile.mkstemp`` does: unpredictable name,
  ``O_EXCL``, so a planted symlink is never followed), flush and fsync it, then ``os.replace`` it onto the target.
  A reader sees the old file or the new one, never a torn one; a full disk leaves the old file.
- :func:`check_output_path` is the CLI habit for outputs: the folder must exist and be writable,
  an output never replaces one of the command's inputs (compared by resolved path and inode)
  nor recorded data (:func:`recorded_data`: a stand log, a flight log), and replacing an
  existing file is reported (``replaced`` in the result) so the command can say so.
- :func:`new_recording_path` never overwrites a recording: it refuses, or picks ``name-2.csv``...

Errors are :class:`~thrustmap.core.errors.ConfigError` naming the path and what was expected.
"""

from __future__ import annotations

import contextlib
import errno
import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from thrustmap.core.errors import ConfigError


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve() or os.path.samefile(a, b)
    except OSError:
        return False


#: suffixes of flight logs (PX4 ULog, ArduPilot DataFlash and telemetry, Betaflight blackbox,
#: ROS 2 bags): recorded data, never an output
FLIGHT_LOG_SUFFIXES = (".ulg", ".bin", ".log", ".tlog", ".bbl", ".bfl", ".mcap", ".db3")


def recorded_data(path: Path) -> str | None:
    """What recorded data an existing file is (None: not recorded data, or not there).

    A stand log recorded by thrustmap (a ``.csv`` with its ``.meta.json`` sidecar, or that
    sidecar), a flight log (by suffix), or any other CSV that is not a Df thrustmap wrote
    (its ``.json`` sidecar says ``thrustmap.df``): a stand or flight log from another tool.
    An output that would replace one is refused; only thrustmap's own products are replaced."""
    if not path.is_file():
        return None
    name = path.name.lower()
    if name.endswith(".meta.json") or path.with_name(path.stem + ".meta.json").exists():
        return "a recorded stand log (it has a .meta.json sidecar)"
    if path.suffix.lower() in FLIGHT_LOG_SUFFIXES:
        return "a flight log"
    if path.suffix.lower() == ".csv" and not _is_df(path.with_suffix(".json")):
        return "a CSV that is not a Df thrustmap wrote (a stand or flight log?)"
    return None


def _is_df(sidecar: Path) -> bool:
    try:
        return '"thrustmap.df"' in sidecar.read_text(encoding="utf-8", errors="replace")[:200]
    except OSError:
        return False


@dataclass(frozen=True)
class OutputPlan:
    """Where an output goes, and whether it replaces an existing file."""

    path: Path
    replaced: bool


def check_output_path(
    path: str | os.PathLike[str],
    *,
    inputs: Iterable[str | os.PathLike[str]] = (),
    what: str = "output",
    renamed: bool = False,
) -> OutputPlan:
    """Check that ``path`` can be written without harm, before any work is done.

    Raises ConfigError when the folder is missing or not writable, when the path is a folder,
    when it is one of ``inputs`` (the same file under any name) or recorded data (unless
    ``renamed``: a recording that takes a new name when its own is taken, never replacing it).
    """
    p = Path(path)
    folder = p.parent if str(p.parent) else Path(".")
    if not folder.exists():
        raise ConfigError(f"{what} folder does not exist; create it first", file=str(folder))
    if not folder.is_dir():
        raise ConfigError(f"{what} folder is not a folder", file=str(folder))
    if not os.access(folder, os.W_OK | os.X_OK):
        raise ConfigError(f"{what} folder is not writable", file=str(folder))
    if p.is_dir():
        raise ConfigError(f"{what} is a folder; expected a file name", file=str(p))
    for inp in inputs:
        if _same_file(p, Path(inp)):
            raise ConfigError(
                f"{what} would overwrite an input file; choose another name", file=str(p)
            )
    if not renamed and (kind := recorded_data(p)) is not None:
        raise ConfigError(
            f"{what} would overwrite {kind}; recorded data is never overwritten: choose another name",
            file=str(p),
        )
    return OutputPlan(path=p, replaced=p.exists())


def new_recording_path(path: str | os.PathLike[str], *, siblings: Iterable[str] = ()) -> Path:
    """A path for a new recording that overwrites nothing.

    ``path`` itself when neither it nor any of its sibling files (``siblings`` are suffixes
    replacing the path's own, e.g. ``(".meta.json",)``) exist; otherwise ``stem-2``, ``stem-3``...
    """
    p = Path(path)
    suffixes = tuple(siblings)

    def taken(candidate: Path) -> bool:
        if candidate.exists():
            return True
        return any(candidate.with_suffix(s).exists() for s in suffixes)

    if not taken(p):
        return p
    for n in range(2, 10_000):
        candidate = p.with_name(f"{p.stem}-{n}{p.suffix}")
        if not taken(candidate):
            return candidate
    raise ConfigError("no free file name for the recording", file=str(p))


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Replace ``path`` with ``data`` atomically (secure temporary in the same folder).

    OSError from the disk (full, read-only, missing folder) becomes a ConfigError naming the
    path; the previous content of ``path`` is left as it was.
    """
    p = Path(path)
    folder = p.parent if str(p.parent) else Path(".")
    try:
        fd, tmp = _create_temporary(folder, p.name)
    except OSError as exc:
        raise ConfigError(f"cannot write here: {_os_reason(exc)}", file=str(p)) from None
    try:
        # mkstemp makes the file private (0600); a map or report is meant to be shared, so give it
        # the mode an ordinary write would (the old file's, else 0666 less the umask)
        os.fchmod(fd, _file_mode(p))
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, p)
    except OSError as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise ConfigError(f"cannot write: {_os_reason(exc)}", file=str(p)) from None
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _create_temporary(folder: Path, name: str) -> tuple[int, str]:
    """What ``tempfile.mkstemp(prefix=f".{name}.", suffix=".tmp", dir=folder)`` does: a new file
    (``O_EXCL``, never through a symlink, mode 0600) under an unpredictable name. Written here
    because importing tempfile (random, shutil and its compressors) costs ~15 ms of CPU at the
    start of every command that writes a file, against a plain pyulog load for one."""
    flags = os.O_RDWR | os.O_CREAT | os.O_EXCL
    for extra in ("O_NOFOLLOW", "O_CLOEXEC", "O_BINARY"):
        flags |= getattr(os, extra, 0)
    for _ in range(100):  # tempfile's TMP_MAX tries
        tmp = os.path.abspath(os.path.join(folder, f".{name}.{os.urandom(6).hex()}.tmp"))
        try:
            return os.open(tmp, flags, 0o600), tmp
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, "no unused temporary file name", str(folder))


def _file_mode(path: Path) -> int:
    try:
        if path.is_file() and not path.is_symlink():
            return path.stat().st_mode & 0o777
    except OSError:
        pass
    umask = os.umask(0o022)  # read the umask (there is no getter) and put it back
    os.umask(umask)
    return 0o666 & ~umask


def atomic_write_text(path: str | os.PathLike[str], text: str) -> None:
    """:func:`atomic_write_bytes` for UTF-8 text."""
    atomic_write_bytes(path, text.encode("utf-8"))


def _os_reason(exc: OSError) -> str:
    if exc.errno == errno.ENOSPC:
        return "the disk is full"
    if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        return "permission denied (read-only folder or file)"
    if exc.errno == errno.ENOENT:
        return "the folder does not exist"
    return exc.strerror or str(exc)
