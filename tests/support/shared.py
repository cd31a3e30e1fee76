"""Where the shared real recordings are: the one place tests find ``../shared/data``.

Test support only. ``THRUSTMAP_SHARED_DATA`` names the folder (a git worktree or a CI checkout
does not always sit beside ``shared``); without it, ``../shared/data`` beside the checkout. The
``shared_data`` fixture (tests/conftest.py) uses this; code that needs the folder while tests
are collected (parametrisation) calls :func:`shared_data_dir` itself.
"""

from __future__ import annotations

import os
from pathlib import Path

PROJECT_ROOT = Path(__file__).resolve().parents[2]
#: the reason a test skips without the folder (tests/skip-allowlist.toml lists it)
ABSENT_REASON = "shared reference data not found (../shared/data; set THRUSTMAP_SHARED_DATA)"


def shared_data_path() -> Path:
    """The folder the tests read, whether it exists or not."""
    env = os.environ.get("THRUSTMAP_SHARED_DATA")
    return Path(env) if env else PROJECT_ROOT.parent / "shared" / "data"


def shared_data_dir() -> Path | None:
    """The shared data folder, or None when it is absent."""
    path = shared_data_path()
    return path if path.is_dir() else None
