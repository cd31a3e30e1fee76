"""Malformed inputs through the real ``thrustmap`` commands (issue 14's examples).

Every case runs through ``thrustmap.cli.main`` in a forked child limited to 1 GB more address
space and 60 s; it must end with exit 0, or exit 2 and exactly one stderr line (never "internal
error"), and inputs a case names must be left untouched.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from fuzz.cli_cases import Case, CliResult, cases, problems, run_cases

ALL = cases()


@pytest.fixture(scope="module")
def results(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[CliResult, Path]]:
    work = tmp_path_factory.mktemp("cli_malformed")
    out = run_cases(ALL, work, timeout_s=60.0)
    return {c.name: (r, work / f"case{k}") for k, (c, r) in enumerate(zip(ALL, out, strict=True))}


@pytest.mark.parametrize("case", ALL, ids=[c.name for c in ALL])
def test_malformed_input_ends_cleanly(
    case: Case, results: dict[str, tuple[CliResult, Path]]
) -> None:
    result, folder = results[case.name]
    assert problems(case, result, folder) == []


def test_dataflash_breaks_are_summarised(results: dict[str, tuple[CliResult, Path]]) -> None:
    result, _ = results["dataflash 720 kB, a break per message"]
    assert result.code == 0
    # Shown once, by inspect's own warning lines: the reader returns its warnings instead of
    # also logging them (issue 24), so stderr stays empty.
    assert result.stderr == ""
    lines = [ln for ln in result.stdout.splitlines() if "warning:" in ln]
    assert 1 <= len(lines) <= 8, lines[:10]  # was 12,556 lines, one per chain break
    assert any("more corrupt stretches" in ln for ln in lines)


def test_time_typo_is_dropped_with_a_warning(results: dict[str, tuple[CliResult, Path]]) -> None:
    result, folder = results["paper CSV time 3005000"]
    assert result.code == 0
    assert "isolated by a time jump" in result.stdout
    assert (folder / "df.csv").stat().st_size < 1_000_000  # bins for the flight, not for 35 days


def test_outputs_say_what_they_replaced(tmp_path: Path) -> None:
    from fuzz.cli_cases import LOGS

    case = Case(
        "export replaces",
        ["export", "m.json", "--to", "c-header", "-o", "old.h"],
        {"m.json": (LOGS / "sim_map.json").read_bytes(), "old.h": b"old\n"},
    )
    [result] = run_cases([case], tmp_path, timeout_s=60.0)
    assert result.code == 0, result.stderr
    assert "replaced the previous file" in result.stderr
    assert (tmp_path / "case0" / "old.h").read_text().startswith("/*")
