"""Small truths a user notices (issue 24): messages, labels, tables, help and the demo line.

Each test fails on the output before the fix: a log prefix, a false label, a shifted column, a
help line past 80 columns, a case-sensitive target, a dry run that repeats its low level.
"""

from __future__ import annotations

import logging
import re
import shutil
from pathlib import Path

import click
import numpy as np
import pytest
from support import simulate_flight as sim

from thrustmap import cli
from thrustmap.cli import main

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"
XNOVA_SR = Path(__file__).resolve().parents[2] / "shared/data/xnova-thrust-stand/single_rotor"


def run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = 0
    try:
        main(args)
    except SystemExit as exc:
        code = int(exc.code or 0)
    out = capsys.readouterr()
    return code, out.out, out.err


# -- log lines ------------------------------------------------------------------------------------


def test_library_warnings_read_like_the_cli_lines(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    @click.command("fine")
    def fine() -> None:
        logging.getLogger("thrustmap.fitting.gamma").warning("γ fit: narrow voltage span")
        logging.getLogger("thrustmap.fitting.gamma").warning("γ fit: narrow voltage span")
        logging.getLogger("thrustmap.rig.runner").error("stand went silent")
        click.echo("result")

    monkeypatch.setattr(cli.LazyGroup, "get_command", lambda self, ctx, name: fine)
    code, out, err = run(["fine"], capsys)
    assert code == 0 and out == "result\n"
    # no logger names, no upper-case level words; the repeated warning shown once
    assert err.splitlines() == ["warning: γ fit: narrow voltage span", "error: stand went silent"]


def test_dataflash_corrupt_tail_is_reported_once(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = tmp_path / "hover.bin"
    sim.write_dataflash(sim.simulate_hover(sim.HoverSim(seed=3, duration_s=40.0)), log)
    data = log.read_bytes()
    log.write_bytes(data[:-7])  # the last message cut short
    code, out, err = run(
        ["flightlog", "extract", str(log), "--mass-kg", "1.0", "-o", str(tmp_path / "df.csv")],
        capsys,
    )
    assert code == 0, err
    assert (out + err).count("corrupt tail") == 1


# -- labels ---------------------------------------------------------------------------------------


def _stand_files() -> list[str]:
    files = sorted(str(p) for p in (FIXTURES / "sweeps").glob("*_run.csv"))
    assert files
    return files


def test_in_sample_table_does_not_call_its_points_held_out(
    capsys: pytest.CaptureFixture[str],
) -> None:
    code, out, err = run(
        ["compare", _stand_files()[0], "--models", "motor,linear", "--validate", "in-sample"],
        capsys,
    )
    assert code == 0, err
    assert "held-out" not in out
    assert "in-sample: every fitted point" in out


def test_inspect_says_completed_not_a_dict(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(["inspect", str(FIXTURES / "sweeps" / "msp_run.csv")], capsys)
    assert code == 0, err
    assert "  outcome: completed\n" in out
    assert "{'status'" not in out
    assert "1000..2000 µs" in out and " us" not in out  # µs in human output


def test_evaluate_columns_stay_aligned_with_a_long_validation_name(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    src = FIXTURES / "sweeps"
    long_name = tmp_path / "a-rather-long-stand-log-name-from-the-bench.csv"
    shutil.copy(src / "msp_run.csv", long_name)
    shutil.copy(src / "msp_run.meta.json", long_name.with_name(long_name.stem + ".meta.json"))
    code, _, err = run(["fit", str(src / "msp_run.csv"), "-o", str(tmp_path / "m.json")], capsys)
    assert code == 0, err
    code, out, err = run(["evaluate", str(tmp_path / "m.json"), str(long_name)], capsys)
    assert code == 0, err
    head, _, row = out.splitlines()[:3]
    for column in (" n ", "mean %", "max %"):
        end = head.index(column) + len(column.rstrip())
        assert row[end - 1] != " " and row[end] == " ", (column, head, row)


# -- help -----------------------------------------------------------------------------------------


def _command_paths() -> list[list[str]]:
    group = cli.cli
    ctx = click.Context(group)
    paths: list[list[str]] = [[]]
    for name in group.list_commands(ctx):
        command = group.get_command(ctx, name)
        assert command is not None
        paths.append([name])
        if isinstance(command, click.Group):
            paths += [[name, sub] for sub in command.commands]
    return paths


def test_every_help_fits_80_columns(capsys: pytest.CaptureFixture[str]) -> None:
    for path in _command_paths():
        code, out, _ = run([*path, "--help"], capsys)
        assert code == 0, path
        wide = [line for line in out.splitlines() if len(line) > 80]
        assert not wide, (path, wide)


@pytest.mark.parametrize("command", ["ports", "probe"])
def test_hardware_identity_help_has_no_pictures_note(
    command: str, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, _ = run([command, "--help"], capsys)
    assert code == 0 and "Pictures:" not in out


def test_export_target_is_matched_without_case(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    src = FIXTURES / "sweeps" / "msp_run.csv"
    code, _, err = run(["fit", str(src), "-o", str(tmp_path / "m.json")], capsys)
    assert code == 0, err
    outputs = []
    for target in ("px4", "PX4"):
        code, out, err = run(["export", str(tmp_path / "m.json"), "--to", target], capsys)
        assert code == 0, (target, err)
        outputs.append(out)
    assert outputs[0] == outputs[1]
    code, _, err = run(["export", str(tmp_path / "m.json"), "--to", "PX5"], capsys)
    assert code == 2 and "unknown target 'PX5'" in err


def test_dry_run_shows_each_level_once_and_no_percent_twice(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = run(
        ["sweep", "steps", "--stand", "sim://tyto-1585", "--throttle", "sim://betaflight",
         "--to", "30", "--dry-run", "-o", str(tmp_path / "run.csv")],
        capsys,
    )  # fmt: skip
    assert code == 0, err
    assert "% (" not in out  # "10.0 % (10 %)": the same level in the same unit, twice
    levels = [line.split()[3] for line in out.splitlines() if " step " in line]
    assert levels == ["15.0", "20.0", "25.0", "30.0"]  # the low level (10 %) is no step


# -- the demo line ---------------------------------------------------------------------------------


def test_demo_sr_vs_mr_is_one_short_sentence_with_the_number() -> None:
    from thrustmap.demo import sr_vs_mr
    from thrustmap.fitting.fit.fitmap import fit_map
    from thrustmap.fitting.loaders.load import load_datasets

    files = [str(p) for p in sorted((FIXTURES / "sweeps").glob("*_run.csv"))]
    sr = fit_map(load_datasets(files[:1]), model="motor").map
    mr = fit_map(load_datasets(files[1:2]), model="motor").map
    line = sr_vs_mr(sr, mr)
    assert len(line) <= 80 and ". " not in line  # one short sentence
    assert "paper measured" not in line
    numbers = [float(x) for x in re.findall(r"[-+]\d+\.\d", line)]
    assert numbers and np.all(np.isfinite(numbers))
