"""The user's top-level folders are the package's subpackages, under one name, for every tool."""

from __future__ import annotations

import importlib
import importlib.util
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
TOP_FOLDERS = ("fitting", "rig", "protocols")


def _source_packages() -> set[str]:
    found = set()
    for init in (ROOT / "thrustmap").rglob("__init__.py"):
        rel = init.parent.relative_to(ROOT)
        found.add(".".join(rel.parts))
    # rglob does not descend into the linked folders on every Python: walk them explicitly
    for top in TOP_FOLDERS:
        for init in (ROOT / top).rglob("__init__.py"):
            rel = init.parent.relative_to(ROOT / top)
            found.add(".".join(["thrustmap", top, *rel.parts]))
    return found


def test_thrustmap_links_to_the_user_folders() -> None:
    for top in TOP_FOLDERS:
        link = ROOT / "thrustmap" / top
        if not link.is_symlink():
            pytest.skip("checkout without symlinks (an installed copy)")
        assert os.readlink(link) == f"../{top}"


def test_every_source_package_imports_under_thrustmap() -> None:
    for name in sorted(_source_packages()):
        module = importlib.import_module(name)
        assert module.__name__ == name


@pytest.mark.parametrize("top", TOP_FOLDERS)
def test_bare_top_level_name_is_refused(top: str) -> None:
    """From the checkout `import fitting` would load the same files a second time."""
    result = subprocess.run(
        [sys.executable, "-c", f"import {top}"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode != 0
    assert f"import thrustmap.{top}, not {top}" in result.stderr


def test_wheel_holds_every_module(tmp_path: Path) -> None:
    if not (ROOT / "pyproject.toml").exists():
        pytest.skip("no source tree")
    # Build from a copy: setuptools writes build/ and *.egg-info into the tree it builds.
    src = tmp_path / "src"
    shutil.copytree(
        ROOT,
        src,
        symlinks=True,  # the package's links to fitting/, rig/, protocols/ stay links
        ignore=shutil.ignore_patterns(".git", ".venv", ".ci-venv", "build", "*.egg-info",
                                      "__pycache__", "thrustmap-demo", ".*_cache"),
    )  # fmt: skip
    out = tmp_path / "dist"
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(out), str(src)],
        check=True, capture_output=True, timeout=300,
    )  # fmt: skip
    (wheel,) = out.glob("thrustmap-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    for top in TOP_FOLDERS:
        for source in (ROOT / top).rglob("*.py"):
            rel = source.relative_to(ROOT / top)
            assert f"thrustmap/{top}/{rel.as_posix()}" in names
    assert not any(n.startswith(("tests/", "support/", "fitting/", "rig/")) for n in names)
