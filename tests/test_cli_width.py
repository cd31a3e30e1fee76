"""A newcomer's first hour (issue 35): help that is found, and output that fits 80 columns.

The README's tour is run command by command on an 80-column terminal (a pty), help included,
and no line may be wider than the terminal. Bare ``thrustmap`` prints its help; a group without
its subcommand a short usage (exit 2), never a one-line "error: Usage".
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest
from click.testing import CliRunner
from support.terminal import DemoRun, run_in_terminal

from thrustmap.cli import cli, textwidth

ROOT = Path(__file__).resolve().parent.parent


def run_cli(*args: str) -> tuple[int, str, str]:
    """``thrustmap ARGS`` in this process (stdout and stderr apart)."""
    result = CliRunner().invoke(cli, list(args), prog_name="thrustmap", terminal_width=80)
    return result.exit_code, result.stdout, result.stderr


def tour_commands() -> list[str]:
    """Every command of the README's tour block (continuation lines joined)."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    block = readme.split("<!-- tour:", 1)[1].split("```sh\n", 1)[1].split("```", 1)[0]
    commands, current = [], ""
    for raw in block.splitlines():
        line = raw.split(" #", 1)[0].strip() if not raw.lstrip().startswith("#") else ""
        if not line:
            continue
        current += " " + line.rstrip("\\").strip()
        if not line.endswith("\\"):
            commands.append(current.strip())
            current = ""
    return commands


def test_readme_is_short_and_has_the_two_setup_commands() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme.splitlines()) <= 150
    assert ".venv/bin/pip install . && .venv/bin/thrustmap demo" in readme
    assert "bash .ci/run" in readme
    commands = tour_commands()
    assert len(commands) >= 10 and all(c.startswith("thrustmap ") for c in commands), commands
    assert any("sim://" in c for c in commands)


@pytest.fixture(scope="module")
def tour(demo_run: DemoRun) -> tuple[Path, list[tuple[int, str]]]:
    """The README's set-up step (``thrustmap demo``: the session's one run, on an 80-column
    terminal), then every tour command in order in its folder (each may use what the one
    before wrote), on an 80-column terminal: the folder and each command's exit code and
    lines."""
    where = demo_run.folder
    assert demo_run.code == 0, demo_run.output
    wide = [ln for ln in demo_run.output.splitlines() if len(ln) > 80]
    assert not wide, wide
    return where, [run_in_terminal(command, where) for command in tour_commands()]


@pytest.mark.parametrize("index", range(len(tour_commands())))
def test_each_tour_command_fits_80_columns(
    tour: tuple[Path, list[tuple[int, str]]], index: int
) -> None:
    where, results = tour
    command = tour_commands()[index]
    code, out = results[index]
    assert code == 0, f"{command}\n{out}"
    wide = [ln for ln in out.splitlines() if len(ln) > 80]
    assert not wide, f"{command}: {wide}"
    name = shlex.split(command)[1]
    sub = shlex.split(command)[2] if name in ("flightlog", "gamma") else ""
    code, out = run_in_terminal(f"thrustmap {name} {sub} --help", where)
    assert code == 0, out
    wide = [ln for ln in out.splitlines() if len(ln) > 80]
    assert not wide, f"{name} {sub} --help: {wide}"


def test_bare_thrustmap_prints_its_help() -> None:
    code, out, err = run_cli()
    assert code == 0 and out.startswith("Usage: thrustmap") and "Commands:" in out, out
    assert "demo" in out and "error:" not in out + err


@pytest.mark.parametrize("group", ["flightlog", "gamma", "fleet"])
def test_a_group_without_its_subcommand_prints_a_short_usage(group: str) -> None:
    code, out, err = run_cli(group)
    assert code == 2 and out == ""
    assert err.startswith(f"Usage: thrustmap {group} ") and "error:" not in err, err
    assert "Commands:" in err and f"thrustmap {group} --help" in err
    assert len(err.splitlines()) > 3 and max(len(ln) for ln in err.splitlines()) <= 80


def test_choices_are_listed_without_tabs() -> None:
    code, _, err = run_cli("plot")
    assert code == 2 and "\t" not in err
    assert "Choose from: surface, slices, residuals" in err, err


def test_usage_never_breaks_inside_a_word() -> None:
    result = CliRunner().invoke(cli, ["sweep", "--help"], prog_name="thrustmap", terminal_width=80)
    usage = result.stdout.split("\n\n", 1)[0]
    assert "stairs-\n" not in usage and "stairs-down" in usage and "stairs-up" in usage, usage
    for choice in ("steps", "stairs-up", "stairs-down", "ramp", "explicit", "adaptive"):
        assert re.search(rf"[{{|]{choice}[|}}]", usage.replace("\n", "").replace(" ", "")), usage
    assert max(len(ln) for ln in result.stdout.splitlines()) <= 80


def test_wrap_breaks_between_words_only_and_keeps_the_indent() -> None:
    line = "  selection (what each rule did): " + ", ".join(f"rule-{i}=1{i}" for i in range(30))
    out = textwidth.wrap(line, 80)
    lines = out.splitlines()
    assert len(lines) > 2 and all(len(ln) <= 80 for ln in lines)
    assert all(ln.startswith("    ") for ln in lines[1:])
    assert out.replace("\n    ", " ") == line  # nothing lost, nothing split
    long_word = "/a/very/" + "long-" * 30 + "path.csv"
    assert textwidth.wrap(f"wrote {long_word}", 80).splitlines() == ["wrote", "  " + long_word]


def test_a_table_that_cannot_fit_turns_vertical() -> None:
    head = ["model", "mean %", "inside supported region"]
    rows = [["motor", "0.388", "n=1039, mean 0.393 %"], ["poly2", "1.997", "n=1039, mean 1.785 %"]]
    wide = textwidth.table(head, rows, right=[False, True, False], cols=80)
    assert wide.splitlines()[0].split() == ["model", "mean", "%", "inside", "supported", "region"]
    narrow = textwidth.table(head, rows, cols=37).splitlines()  # 38 wide in rows: vertical
    assert narrow[:2] == ["model:                   motor", "mean %:                  0.388"]
    assert narrow[2:4] == ["inside supported region: n=1039, mean", " " * 25 + "0.393 %"]
    assert narrow[4] == "" and narrow[5].endswith("poly2")
    assert max(len(ln) for ln in narrow) <= 37


def test_piped_output_keeps_whole_lines(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("COLUMNS", "80")  # exported by readline into child processes: not read
    assert textwidth.width() is None and textwidth.wrap("x " * 100) == "x " * 100
