"""The package is whole in any checkout: real folders under thrustmap/, no symbolic links, one
name per module, every module in the wheel (issue 25)."""

from __future__ import annotations

import ast
import importlib
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "thrustmap"
TOP_FOLDERS = ("fitting", "rig", "protocols")
LAYERS = ("core", "protocols", "rig", "fitting")


def _source_packages() -> set[str]:
    return {".".join(init.parent.relative_to(ROOT).parts) for init in PACKAGE.rglob("__init__.py")}


def test_no_symbolic_link_in_the_tree() -> None:
    """Git on Windows checks links out as text files: nothing the package needs may be one."""
    tracked = subprocess.run(
        ["git", "ls-files", "-s"], cwd=ROOT, capture_output=True, text=True, check=False
    )
    if tracked.returncode != 0:
        pytest.skip("not a git checkout")
    links = [
        line.split("\t", 1)[1] for line in tracked.stdout.splitlines() if line.startswith("120000")
    ]
    assert links == []
    for path in PACKAGE.rglob("*"):
        assert not path.is_symlink(), path


@pytest.mark.parametrize("top", TOP_FOLDERS)
def test_top_level_folder_names_where_the_code_lives(top: str) -> None:
    folder = ROOT / top
    assert not (folder / "__init__.py").exists()  # not importable under a second name
    assert f"thrustmap/{top}/" in (folder / "README.md").read_text(encoding="utf-8")


def test_every_source_package_imports_under_thrustmap() -> None:
    names = sorted(_source_packages())
    assert {f"thrustmap.{layer}" for layer in LAYERS} <= set(names)
    for name in names:
        module = importlib.import_module(name)
        assert module.__name__ == name


@pytest.mark.parametrize("top", TOP_FOLDERS)
def test_bare_top_level_name_is_not_a_module(top: str) -> None:
    """From the checkout `import fitting` must not load the same files a second time."""
    result = subprocess.run(
        [sys.executable, "-c", f"import {top}; print({top}.__file__)"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode != 0 or "thrustmap" not in result.stdout


def _imports(path: Path) -> set[str]:
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module:
            found.add(node.module)
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
    return found


def test_the_shared_ground_imports_no_layer_above_it() -> None:
    above = ("thrustmap.fitting", "thrustmap.rig", "thrustmap.protocols", "thrustmap.cli",
             "thrustmap.report", "thrustmap.demo")  # fmt: skip
    for source in (PACKAGE / "core").rglob("*.py"):
        bad = [m for m in _imports(source) if m.startswith(above)]
        assert not bad, (source.name, bad)


def test_imports_are_absolute() -> None:
    """One import style: ``from thrustmap.x import y`` everywhere, no relative imports."""
    for source in PACKAGE.rglob("*.py"):
        tree = ast.parse(source.read_text(encoding="utf-8"))
        relative = [n.lineno for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.level]
        assert not relative, (source, relative)


def test_wheel_holds_every_module(tmp_path: Path) -> None:
    if not (ROOT / "pyproject.toml").exists():
        pytest.skip("no source tree")
    # Build from a copy: setuptools writes build/ and *.egg-info into the tree it builds.
    src = tmp_path / "src"
    shutil.copytree(
        ROOT,
        src,
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
    for source in PACKAGE.rglob("*.py"):
        assert source.relative_to(ROOT).as_posix() in names
    assert not any(
        n.startswith(("tests/", "support/", "fitting/", "rig/", "protocols/")) for n in names
    )
    assert not any(os.sep + "__pycache__" in n for n in names)
