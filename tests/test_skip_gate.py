"""The skip gate of .ci/run (issue 42 item 3): a skip whose reason is not on
tests/skip-allowlist.toml fails CI; the allowed ones are tabled with their evidence."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from support import skip_gate
from support.public_data import ABSENT_REASON as PUBLIC_ABSENT

TESTS = Path(__file__).resolve().parent
GATE = TESTS / "support" / "skip_gate.py"

SKIPPING_TESTS = f"""
import pytest

def test_allowed():
    pytest.skip({PUBLIC_ABSENT!r})

def test_unlisted():
    pytest.skip("the machine is busy")

def test_runs():
    assert True
"""


def _pytest_with_report(folder: Path, report: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p",
         "support.skip_gate", "--skip-report", str(report), str(folder)],
        capture_output=True, text=True, cwd=folder, timeout=120, check=False,
        env={"PYTHONPATH": str(TESTS), "PATH": "/usr/bin:/bin"},
    )  # fmt: skip


def _gate(report: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, str(GATE), str(report)],
        capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip


def test_an_unlisted_skip_fails_the_gate_and_the_table_names_it(tmp_path: Path) -> None:
    (tmp_path / "test_some.py").write_text(SKIPPING_TESTS)
    report = tmp_path / "skips.json"
    run = _pytest_with_report(tmp_path, report)
    assert run.returncode == 0, run.stdout + run.stderr  # pytest itself passes with skips
    skips = json.loads(report.read_text())
    assert sorted(s["nodeid"].split("::")[1] for s in skips) == ["test_allowed", "test_unlisted"]
    gate = _gate(report)
    assert gate.returncode == 1, gate.stdout
    lines = gate.stdout.splitlines()
    assert any(ln.split()[:2] == ["1", "NO"] and "the machine is busy" in ln for ln in lines)
    assert any(ln.split()[:2] == ["1", "yes"] and PUBLIC_ABSENT in ln for ln in lines)
    assert "FAIL: 1 skip(s)" in gate.stdout
    assert gate.stdout.rstrip().endswith("test_some.py::test_unlisted")


def test_only_allowed_skips_pass_the_gate(tmp_path: Path) -> None:
    (tmp_path / "test_some.py").write_text(SKIPPING_TESTS.replace("the machine is busy",
                                                                  PUBLIC_ABSENT))  # fmt: skip
    report = tmp_path / "skips.json"
    assert _pytest_with_report(tmp_path, report).returncode == 0
    gate = _gate(report)
    assert gate.returncode == 0, gate.stdout
    assert "   2  yes" in gate.stdout and "evidence instead: " in gate.stdout


def test_a_module_skipped_whole_is_counted(tmp_path: Path) -> None:
    (tmp_path / "test_mod.py").write_text(
        "import pytest\npytest.importorskip('no_such_module_here')\n"
    )
    report = tmp_path / "skips.json"
    _pytest_with_report(tmp_path, report)
    (skip,) = json.loads(report.read_text())
    assert "no_such_module_here" in skip["reason"]
    assert _gate(report).returncode == 1


def test_the_committed_allow_list_says_why_and_where_the_evidence_is(tmp_path: Path) -> None:
    entries = skip_gate.load_allowlist()
    assert 1 <= len(entries) <= 10  # short
    assert skip_gate.allowed_by(PUBLIC_ABSENT, entries) is not None
    # the shared data is beside the clone in CI: its absence is not an excuse
    from support.shared import ABSENT_REASON as SHARED_ABSENT

    assert skip_gate.allowed_by(SHARED_ABSENT, entries) is None
    bad = tmp_path / "allow.toml"
    bad.write_text('[[skip]]\nreason = "x"\nwhy = "because"\n')
    with pytest.raises(ValueError, match="entry 1 lacks evidence"):
        skip_gate.load_allowlist(bad)
