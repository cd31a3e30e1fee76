"""The installed package's version, read from its metadata only when asked for (importing
``importlib.metadata`` costs ~60 ms, which every CLI start would otherwise pay)."""

from __future__ import annotations

from functools import cache


@cache
def package_version() -> str:
    """thrustmap's version (``0.0.0+unknown`` when running from a source tree without an install)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("thrustmap")
    except PackageNotFoundError:  # running from a source tree without an install
        return "0.0.0+unknown"
