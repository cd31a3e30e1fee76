"""The CLI starts fast: `--help` imports no heavy library (timing lives in benchmarks/)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

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


EXTRACT_PROBE = """
import json, os, sys
from thrustmap.cli import main
try:
    main({argv!r})
except SystemExit:
    pass
loaded = sorted({{m.split('.')[0] for m in sys.modules}} & {{"pandas", "scipy", "dask", "matplotlib"}})
threads = {{v: os.environ.get(v) for v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}}
sys.stderr.write("PROBE=" + json.dumps([loaded, threads]) + "\\n")
"""


def _probe_extract(argv: list[str], env: dict[str, str]) -> tuple[list[str], dict[str, str]]:
    code = EXTRACT_PROBE.format(argv=argv)
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env
    )
    line = [x for x in result.stderr.splitlines() if x.startswith("PROBE=")]
    assert line, result.stderr
    loaded, threads = json.loads(line[-1][len("PROBE=") :])
    return loaded, threads


def _env_without_thread_vars() -> dict[str, str]:
    import os

    from thrustmap.cli import BLAS_THREAD_VARS

    return {k: v for k, v in os.environ.items() if k not in BLAS_THREAD_VARS}


@pytest.mark.parametrize("log", ["bb_hover_sim.bbl", "sim_hover.ulg"])
def test_flightlog_extract_loads_no_pandas_scipy_or_dask(log: str, tmp_path: Path) -> None:
    src = Path(__file__).resolve().parent.parent / "fixtures/flightlogs" / log
    argv = ["flightlog", "extract", str(src), "--mass-kg", "1.0", "-o", str(tmp_path / "df.csv")]
    argv += ["--settle-s", "1"]  # the blackbox fixture's 4 s and 3 s logs: not too short then
    loaded, threads = _probe_extract(argv, _env_without_thread_vars())
    assert (tmp_path / "df.csv").is_file()
    assert loaded == []
    # the CLI runs numpy's BLAS on one thread (no command gains from more; they cost start-up)
    assert threads == {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}


def test_cli_keeps_the_users_thread_setting(tmp_path: Path) -> None:
    env = {**_env_without_thread_vars(), "OMP_NUM_THREADS": "3"}
    _, threads = _probe_extract(["--version"], env)
    assert threads == {"OPENBLAS_NUM_THREADS": None, "OMP_NUM_THREADS": "3"}


def test_limit_blas_threads_sets_them_only_when_none_is_set() -> None:
    from thrustmap.cli import limit_blas_threads

    env: dict[str, str] = {"PATH": "/bin"}
    assert limit_blas_threads(env) is True
    assert env == {"PATH": "/bin", "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
                   "MKL_NUM_THREADS": "1"}  # fmt: skip
    mine = {"MKL_NUM_THREADS": "8"}
    assert limit_blas_threads(mine) is False
    assert mine == {"MKL_NUM_THREADS": "8"}
