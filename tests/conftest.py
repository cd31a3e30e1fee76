"""Shared test fixtures.

``shared_data``: the real recordings in ../shared/data (beside the project, or
``THRUSTMAP_SHARED_DATA``): every test that reads them takes the folder from this fixture (or,
while collecting, from ``support.shared.shared_data_dir``). ``public_data``: the public files of
benchmarks/public-data.toml by name, size and sha256 checked. Tests that need either skip with
an allow-listed reason (tests/skip-allowlist.toml) when it is absent (a fresh clone elsewhere).
``demo_run``: ``thrustmap demo`` run once for the whole session (it takes ~30 s).
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from support import public_data as pd
from support.shared import ABSENT_REASON, shared_data_dir
from support.skip_gate import (  # noqa: F401 - hooks: --skip-report (the CI's skip table)
    pytest_addoption,
    pytest_collectreport,
    pytest_runtest_logreport,
    pytest_sessionfinish,
)
from support.terminal import DemoRun

# With pyarrow installed (the fleet extra), pandas keeps strings in Arrow, whose default
# allocators (mimalloc/jemalloc) reserve large address ranges up front, so the fuzz suite's
# children (run under RLIMIT_AS) fail a 384-byte malloc. The system allocator makes that limit
# measure what a command uses. Set before anything imports pandas (and so pyarrow).
os.environ.setdefault("ARROW_DEFAULT_MEMORY_POOL", "system")

PROJECT_ROOT = Path(__file__).resolve().parent.parent
FIXTURES = PROJECT_ROOT / "fixtures"


@pytest.fixture
def shared_data() -> Path:
    folder = shared_data_dir()
    if folder is None:
        pytest.skip(ABSENT_REASON)
    return folder


@pytest.fixture
def public_data() -> pd.PublicFiles:
    """The files of benchmarks/public-data.toml: ``public_data("erle/31-3-2015_83")``."""
    folder = pd.public_data_dir()
    if folder is None:
        pytest.skip(pd.ABSENT_REASON)
    return pd.PublicFiles(folder)


@pytest.fixture
def fixtures_dir() -> Path:
    return FIXTURES


@pytest.fixture(autouse=True)
def fresh_simulated_benches() -> None:
    """sim:// peers of one process share named benches (one plant each); every test starts
    with none, so plants never see two tests' clocks."""
    import sys

    peers = sys.modules.get("thrustmap.rig.sim.peers")
    if peers is not None:
        peers.reset_benches()


@pytest.fixture(scope="session")
def demo_run(tmp_path_factory: pytest.TempPathFactory) -> DemoRun:
    """The demo, once per session: tests read its files and write theirs beside them (the
    README's tour writes into ``folder``, the report tests into ``thrustmap-demo``), never
    over them."""
    from support.terminal import run_in_terminal

    where = tmp_path_factory.mktemp("demo-run")
    (where / "fixtures").symlink_to(FIXTURES)
    # the README's `thrustmap demo`, its folder named in full: the maps then record their
    # logs' full paths, so a report of them works from any folder
    code, output = run_in_terminal('thrustmap demo -o "$PWD/thrustmap-demo"', where, timeout_s=600)
    return DemoRun(where, code, output)
