"""The documentation site builds with warnings as errors, and its CLI reference is generated
from the click commands (issue 35): every command appears without being written by hand."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from thrustmap.cli import COMMANDS

ROOT = Path(__file__).resolve().parent.parent


def test_mkdocs_build_strict_generates_the_cli_reference(tmp_path: Path) -> None:
    pytest.importorskip("mkdocs_click", reason="the docs extra is not installed")
    mkdocs = shutil.which("mkdocs", path=str(Path(sys.executable).parent)) or shutil.which("mkdocs")
    assert mkdocs, "mkdocs is importable but its command is not on PATH"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "NO_MKDOCS_2_WARNING": "1"}
    proc = subprocess.run(
        [mkdocs, "build", "--strict", "-d", str(tmp_path / "site")],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    cli_page = (tmp_path / "site" / "cli" / "index.html").read_text(encoding="utf-8")
    for name in COMMANDS:
        assert f'id="thrustmap-{name}"' in cli_page, name
    # written by hand, the page would not carry the options' help text
    assert "--target-pi" in cli_page and "thrustmap flightlog extract" in cli_page
    source = (ROOT / "docs" / "cli.md").read_text(encoding="utf-8")
    assert "::: mkdocs-click" in source and "--target-pi" not in source


def test_readme_links_point_at_pages_that_exist() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    links = re.findall(r"\]\(([^)#]+\.md)", readme)
    assert len(links) >= 10
    missing = [link for link in links if not (ROOT / link).is_file()]
    assert not missing, missing
