"""The public files behind the docs' figures, by their name in benchmarks/public-data.toml.

Test and benchmark support only (never product code). The files are not in the repository: they
sit under ``THRUSTMAP_PUBLIC_DATA`` (default: ``$THRUSTMAP_SHARED_DATA/public``, then
``../shared/data/public`` beside the checkout) at ``<source dir>/<path>``. Every file is checked
against the manifest's size and sha256 before it is used; a mismatch fails loudly, naming the
entry.

    python tests/support/public_data.py [--dir DIR]    # check every entry, one line each
"""

from __future__ import annotations

import argparse
import hashlib
import os
import sys
from dataclasses import dataclass
from functools import cache
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # the test extra installs tomli on 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[2]
MANIFEST = ROOT / "benchmarks" / "public-data.toml"
#: the reason a test skips when the files are absent (tests/skip-allowlist.toml lists it)
ABSENT_REASON = "public data not found (benchmarks/public-data.toml; set THRUSTMAP_PUBLIC_DATA)"


class PublicDataError(Exception):
    """A manifest entry whose file is missing or is not the bytes the manifest pins."""


@dataclass(frozen=True)
class Entry:
    name: str
    source: str
    repository: str
    commit: str
    path: str
    local: str  # relative to the public-data folder
    size_bytes: int
    sha256: str
    role: str  # "development" or "set-aside"
    shared: str | None  # the same bytes under this name in ../shared/data


@cache
def manifest(path: Path = MANIFEST) -> dict[str, Entry]:
    data = tomllib.loads(path.read_text(encoding="utf-8"))
    entries: dict[str, Entry] = {}
    for name, f in data["file"].items():
        src = data["source"][f["source"]]
        role = f.get("role", src["role"])
        if role not in ("development", "set-aside"):
            raise PublicDataError(f"{path}: {name}: role {role!r}, expected development|set-aside")
        entries[name] = Entry(
            name=name,
            source=f["source"],
            repository=src["repository"],
            commit=f.get("commit", src["commit"]),  # a file deleted later: a commit holding it
            path=f["path"],
            local=f"{src['dir']}/{f['path']}",
            size_bytes=int(f["size"]),
            sha256=f["sha256"],
            role=role,
            shared=f.get("shared"),
        )
    return entries


def public_data_dir() -> Path | None:
    """The folder holding the files, or None when none of the default places is a folder
    (THRUSTMAP_PUBLIC_DATA naming no folder is an error, not a reason to skip)."""
    env = os.environ.get("THRUSTMAP_PUBLIC_DATA")
    if env:
        if not Path(env).is_dir():
            raise PublicDataError(f"THRUSTMAP_PUBLIC_DATA={env}: not a folder")
        return Path(env)
    shared = os.environ.get("THRUSTMAP_SHARED_DATA")
    candidates = ([Path(shared) / "public"] if shared else []) + [
        ROOT.parent / "shared" / "data" / "public"
    ]
    return next((c for c in candidates if c.is_dir()), None)


def names(source: str | None = None, role: str | None = None) -> list[str]:
    return [
        e.name
        for e in manifest().values()
        if (source is None or e.source == source) and (role is None or e.role == role)
    ]


@cache
def _checked(path: Path, mtime_ns: int, size: int) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def resolve(name: str, folder: Path | None = None) -> Path:
    """The file of manifest entry ``name``, its size and sha256 checked."""
    entry = manifest().get(name)
    if entry is None:
        raise PublicDataError(f"{name}: not an entry of {MANIFEST.name}")
    folder = folder or public_data_dir()
    if folder is None:
        raise PublicDataError(f"{name}: {ABSENT_REASON}")
    path = folder / entry.local
    if not path.is_file():
        raise PublicDataError(
            f"{name}: {path} is missing (from {entry.repository} at {entry.commit[:10]}, "
            f"path {entry.path})"
        )
    st = path.stat()
    if st.st_size != entry.size_bytes:
        raise PublicDataError(
            f"{name}: {path} is {st.st_size} bytes, the manifest pins {entry.size_bytes}"
        )
    sha = _checked(path, st.st_mtime_ns, st.st_size)
    if sha != entry.sha256:
        raise PublicDataError(f"{name}: {path} has sha256 {sha}, the manifest pins {entry.sha256}")
    return path


@dataclass(frozen=True)
class PublicFiles:
    """The public-data folder: call it with a manifest name for the checked file."""

    folder: Path

    def __call__(self, name: str) -> Path:
        return resolve(name, self.folder)

    def names(self, source: str | None = None, role: str | None = None) -> list[str]:
        return names(source, role)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="check every entry of benchmarks/public-data.toml")
    ap.add_argument(
        "--dir", type=Path, help="the public-data folder (default as the tests find it)"
    )
    a = ap.parse_args(argv)
    try:
        folder = a.dir or public_data_dir()
    except PublicDataError as exc:
        print(f"error: {exc}")
        return 2
    if folder is None:
        print(ABSENT_REASON)
        return 2
    bad = 0
    for name, e in manifest().items():
        try:
            resolve(name, folder)
            print(f"ok   {name:40s} {e.role:11s} {e.repository}@{e.commit[:10]}:{e.path}")
        except PublicDataError as exc:
            bad += 1
            print(f"FAIL {exc}")
    print(f"{len(manifest()) - bad} of {len(manifest())} entries verified in {folder}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
