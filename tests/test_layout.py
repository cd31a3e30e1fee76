"""The house: modules of one job each, and the design page's list of the large ones (issue 35
item 5)."""

from __future__ import annotations

import importlib
import re
import types
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "thrustmap"
DESIGN = ROOT / "docs" / "design.md"
MAX_LINES = 700


def _lines(path: Path) -> int:
    return len(path.read_text(encoding="utf-8").splitlines())


def _large_modules_listed() -> dict[str, str]:
    """``docs/design.md``'s "Large modules" section: module (relative to thrustmap/) -> reason."""
    text = DESIGN.read_text(encoding="utf-8")
    m = re.search(r"^## Large modules\n(.*?)(?=^## |\Z)", text, re.M | re.S)
    assert m, "docs/design.md has no '## Large modules' section"
    listed: dict[str, str] = {}
    for item in re.split(r"^- ", m.group(1), flags=re.M)[1:]:
        head = re.match(r"`([^`]+\.py)`:\s*(.*)", " ".join(item.split()))
        assert head, f"expected '- `module.py`: reason', got {item[:60]!r}"
        listed[head.group(1)] = head.group(2)
    return listed


def test_every_module_over_700_lines_is_named_in_the_design_page_with_a_reason() -> None:
    big = {
        str(p.relative_to(PACKAGE)): _lines(p)
        for p in PACKAGE.rglob("*.py")
        if _lines(p) > MAX_LINES
    }
    listed = _large_modules_listed()
    missing = sorted(set(big) - set(listed))
    assert not missing, f"modules over {MAX_LINES} lines not in docs/design.md: {missing}"
    for name, reason in listed.items():
        assert len(reason.split()) >= 4, f"{name}: give the reason it is one module"
        path = PACKAGE / name
        assert path.is_file(), f"docs/design.md lists {name}, which does not exist (split?)"
        assert _lines(path) > MAX_LINES, (
            f"docs/design.md lists {name} as large, but it has {_lines(path)} lines: drop its line"
        )


@pytest.mark.parametrize(
    ("package", "names"),
    [
        ("thrustmap.fitting.df", ["DfOptions", "Df", "extract", "read_df", "write_df",
                                  "airborne_windows", "plausible_timeline", "hover_throttle",
                                  "map_extrapolation", "thrust_from_motors", "G0"]),
        ("thrustmap.fitting.selection", ["Selection", "Points", "select", "describe",
                                         "plateaus", "rest_zero", "ROLE_PLATEAU"]),
        ("thrustmap.fitting.loaders", ["ColumnMap", "load_dataset", "load_datasets",
                                       "is_step_summary", "check_thrust_leaves_noise"]),
        ("thrustmap.fitting.fit", ["fit_map", "pool", "Pool", "Row", "validate", "compare",
                                   "evaluate", "backemf_rows", "bound_term"]),
        ("thrustmap.fitting.export.firmware", ["export_px4", "export_ardupilot",
                                               "export_betaflight", "fit_px4",
                                               "ardupilot_spin_min", "cells_from_voltage"]),
    ],
)  # fmt: skip
def test_a_split_module_keeps_its_import_path(package: str, names: list[str]) -> None:
    mod = importlib.import_module(package)
    assert Path(str(mod.__file__)).name == "__init__.py"
    for name in names:
        assert name in mod.__all__, name
        # a submodule named like a re-exported function must not shadow it
        assert not isinstance(getattr(mod, name), types.ModuleType), name
    for module in sorted(Path(str(mod.__file__)).parent.glob("*.py")):
        assert _lines(module) <= MAX_LINES, f"{module.name}: {_lines(module)} lines"


def test_the_fleet_rules_key_covers_every_module_of_the_df_rules(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A Df rule edited in any module of ``fitting/df/`` must change the fleet's options key
    (a re-run then re-extracts): the key hashes every one of them."""
    from thrustmap.fleet import run

    read: list[Path] = []
    original = Path.read_bytes

    def spy(self: Path) -> bytes:
        read.append(self.resolve())
        return original(self)

    monkeypatch.setattr(Path, "read_bytes", spy)
    run.rules_fingerprint()
    df_modules = {p.resolve() for p in (PACKAGE / "fitting" / "df").glob("*.py")}
    assert len(df_modules) > 1 and df_modules <= set(read)
