"""The user's top-level folders install as subpackages of `thrustmap`, all of them."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
MAPPED = {
    "thrustmap": "thrustmap",
    "fitting": "thrustmap.fitting",
    "rig": "thrustmap.rig",
    "protocols": "thrustmap.protocols",
}


def _declared_packages() -> list[str]:
    if sys.version_info < (3, 11):
        pytest.skip("tomllib needs Python 3.11")
    import tomllib

    data = tomllib.loads((ROOT / "pyproject.toml").read_text())
    return list(data["tool"]["setuptools"]["packages"])


def test_every_source_package_is_declared_and_importable() -> None:
    declared = set(_declared_packages())
    found = set()
    for top, name in MAPPED.items():
        for init in (ROOT / top).rglob("__init__.py"):
            rel = init.parent.relative_to(ROOT / top)
            found.add(".".join([name, *rel.parts]) if rel.parts else name)
    assert found - declared == set(), "add these to [tool.setuptools] packages in pyproject.toml"
    for name in sorted(found):
        importlib.import_module(name)


def test_no_generic_top_level_modules_installed() -> None:
    import thrustmap.fitting

    assert thrustmap.fitting.__name__ == "thrustmap.fitting"
    for generic in ("fitting", "rig", "protocols"):
        spec = importlib.util.find_spec(generic)
        assert spec is None or Path(spec.origin or "").parent.parent == ROOT, generic
