"""The CLI starts fast: `--help` imports no heavy library (timing lives in benchmarks/)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from thrustmap.cli import COMMANDS, SUMMARIES

HEAVY = ("numpy", "pandas", "scipy", "pymavlink", "serial", "matplotlib", "plotly", "pyulog")

PROBE = """
import json, sys
from thrustmap.cli import main
try:
    main({argv!r})
except SystemExit:
    pass
heavy = sorted({{m.split('.')[0] for m in sys.modules}} & set({heavy!r}))
sys.stderr.write("HEAVY=" + json.dumps(heavy) + "\\n")
"""


def _heavy_modules_loaded(argv: list[str]) -> list[str]:
    code = PROBE.format(argv=argv, heavy=list(HEAVY))
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120
    )
    line = [x for x in result.stderr.splitlines() if x.startswith("HEAVY=")]
    assert line, result.stderr
    return list(json.loads(line[-1][len("HEAVY=") :]))


def test_every_command_has_a_summary() -> None:
    assert set(SUMMARIES) >= set(COMMANDS)


@pytest.mark.parametrize("argv", [["--help"], ["--version"]])
def test_top_level_help_imports_nothing_heavy(argv: list[str]) -> None:
    assert _heavy_modules_loaded(argv) == []


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_command_help_imports_nothing_heavy(command: str) -> None:
    assert _heavy_modules_loaded([command, "--help"]) == []
