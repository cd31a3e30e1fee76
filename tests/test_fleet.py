"""`thrustmap fleet extract` in the plain serial loop: outcomes, the Parquet table, resuming."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pandas as pd
import pytest
from support.fleet_gen import Fleet, make_fleet

from thrustmap.cli import main
from thrustmap.fleet.table import read_table
from thrustmap.fleet.task import Outcome

pytest.importorskip("pyarrow")


def run_cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    try:
        main(args)
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def extract_args(fleet: Fleet, out: Path, *extra: str) -> list[str]:
    return ["fleet", "extract", str(fleet.folder), "-o", str(out), "--masses",
            str(fleet.masses_csv), "--map", str(fleet.stand_map), "--workers", "0", "--quiet",
            *extra]  # fmt: skip


@pytest.fixture(scope="module")
def small_fleet(tmp_path_factory: pytest.TempPathFactory) -> Fleet:
    return make_fleet(tmp_path_factory.mktemp("fleet"), 2)


def by_path(outcomes: list[Outcome]) -> dict[Path, Outcome]:
    return {Path(o.path): o for o in outcomes}


def test_every_log_has_an_outcome_and_each_df_is_flightlog_extracts(
    small_fleet: Fleet, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    code, stdout, err = run_cli(extract_args(small_fleet, out), capsys)
    assert code == 0, err
    rows = by_path(read_table(out / "fleet.parquet"))
    expected = set(small_fleet.good) | set(small_fleet.corrupt) | set(small_fleet.no_mass)
    assert set(rows) == {p.absolute() for p in expected}
    for path, word in small_fleet.corrupt.items():
        o = rows[path.absolute()]
        assert o.status == "refused" and o.reason.startswith(str(path.absolute()))
        assert word in o.reason and "\n" not in o.reason
        assert f"refused: {o.reason}" in stdout
    for path in small_fleet.no_mass:
        assert "give the vehicle mass" in rows[path.absolute()].reason
    # each good log: exactly what `flightlog extract` writes for it, with the same options
    for path, af in small_fleet.good.items():
        o = rows[path.absolute()]
        assert o.status == "ok", o.reason
        assert o.mass_kg == af.mass_kg and o.rotors == 4 and o.samples > 50
        assert o.dropped_s["settle"] > 0 and o.voltage_max_v > o.voltage_min_v
        single = tmp_path / f"{path.stem}.csv"
        code, _, err = run_cli(
            [
                "flightlog",
                "extract",
                str(path),
                "--mass-kg",
                str(af.mass_kg),
                "--map",
                str(small_fleet.stand_map),
                "-o",
                str(single),
            ],  # fmt: skip
            capsys,
        )
        assert code == 0, err
        ours = pd.read_csv(out / o.df_path)
        assert len(ours) == o.samples
        pd.testing.assert_frame_equal(ours, pd.read_csv(single))
    # one airframe per (format, mass): four groups of two logs
    keys = {o.airframe_key for o in rows.values() if o.status == "ok"}
    assert len(keys) == 4
    assert "4 refused" in stdout or "5 refused" in stdout


def test_a_rerun_skips_what_is_done_and_redoes_only_what_changed(
    small_fleet: Fleet, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    logs = tmp_path / "logs"
    shutil.copytree(small_fleet.folder, logs)
    fleet = Fleet(logs, small_fleet.masses_csv, small_fleet.stand_map)
    out = tmp_path / "out"
    assert run_cli(extract_args(fleet, out), capsys)[0] == 0
    first = by_path(read_table(out / "fleet.parquet"))
    assert not any(o.reused for o in first.values())
    code, stdout, _ = run_cli(extract_args(fleet, out), capsys)
    assert code == 0
    second = by_path(read_table(out / "fleet.parquet"))
    assert all(o.reused and o.seconds == 0 for o in second.values())
    assert f"{len(first)} already done" in stdout
    # a log whose content changes is redone; one copied under a new name is found by its hash
    victim = next(p for p in sorted(logs.rglob("px4quad-*.ulg")))
    other = next(p for p in sorted(logs.rglob("apquad-*.bin")))
    victim.write_bytes(other.read_bytes()[:20000])  # now a torn DataFlash
    twin = logs / "apquad" / "apquad-copy.bin"
    shutil.copy(other, twin)
    assert run_cli(extract_args(fleet, out), capsys)[0] == 0
    third = by_path(read_table(out / "fleet.parquet"))
    assert not third[victim].reused and third[victim].sha256 != first[victim].sha256
    assert third[twin].reused and third[twin].df_path == first[other].df_path
    assert sum(not o.reused for o in third.values()) == 1
    # other options: every log is redone (the options key differs), the twins once
    assert run_cli(extract_args(fleet, out, "--tilt-max-deg", "12"), capsys)[0] == 0
    fourth = read_table(out / "fleet.parquet")
    assert [Path(o.path).name for o in fourth if o.reused] == ["apquad-copy.bin"]
    assert {o.options_key for o in fourth}.isdisjoint({o.options_key for o in first.values()})


def test_bad_requests_are_one_line_and_exit_2(
    small_fleet: Fleet, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = str(tmp_path / "out")
    cases = [
        (["fleet", "extract", str(tmp_path / "nope"), "-o", out], "no such file or folder"),
        (["fleet", "extract", str(tmp_path / "*.ulg"), "-o", out], "matches no file"),
        (
            [
                "fleet",
                "extract",
                str(small_fleet.folder),
                "-o",
                out,
                "--workers",
                "2",
                "--scheduler",
                "tcp://127.0.0.1:1",
            ],
            "not both",
        ),  # fmt: skip
        (
            ["fleet", "extract", str(small_fleet.folder), "-o", out, "--memory-per-worker", "lots"],
            "expected e.g. 2GiB",
        ),  # fmt: skip
    ]
    cases.append((["fleet", "gamma", str(tmp_path / "never-extracted")], "fleet table not found"))
    bad_masses = tmp_path / "m.csv"
    bad_masses.write_text("pattern,mass_kg\npx4*,1.0\napquad*,heavy\n", encoding="utf-8")
    cases.append(
        (
            ["fleet", "extract", str(small_fleet.folder), "-o", out, "--masses", str(bad_masses)],
            f"{bad_masses}:3: column 'mass_kg'",
        ),  # fmt: skip
    )
    for args, text in cases:
        code, _, err = run_cli(args, capsys)
        assert code == 2, (args, err)
        assert len(err.strip().splitlines()) == 1 and text in err, err


def test_a_log_over_the_size_limit_is_refused_unread(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    big = tmp_path / "logs" / "big.ulg"
    big.parent.mkdir()
    with open(big, "wb") as f:
        f.truncate(3 * 2**20)  # sparse: 3 MiB of zeros
    out = tmp_path / "out"
    code, _, err = run_cli(
        [
            "fleet",
            "extract",
            str(big.parent),
            "-o",
            str(out),
            "--mass-kg",
            "1",
            "--workers",
            "0",
            "--max-log-mb",
            "1",
        ],  # fmt: skip
        capsys,
    )
    assert code == 0, err
    (o,) = read_table(out / "fleet.parquet")
    assert o.status == "refused" and "over the per-log limit of 1 MiB" in o.reason
    assert o.sha256 == ""  # not even hashed
    assert os.listdir(out / "df") == []


def test_fleet_gamma_is_gamma_fit_per_airframe_with_the_default_loss(
    small_fleet: Fleet, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import json

    out = tmp_path / "out"
    assert run_cli(extract_args(small_fleet, out), capsys)[0] == 0
    code, stdout, err = run_cli(
        [
            "fleet",
            "gamma",
            str(out),
            "--map",
            str(small_fleet.stand_map),
            "--min-logs",
            "2",
            "--json",
        ],  # fmt: skip
        capsys,
    )
    assert code == 0, err
    groups = json.loads(stdout)
    assert len(groups) == 4 and all(g["status"] == "fitted" for g in groups)
    for g in groups:
        code, alone, err = run_cli(
            [
                "gamma",
                "fit",
                *g["df"],
                "--map",
                str(small_fleet.stand_map),
                "-o",
                str(tmp_path / f"{g['key']}.json"),
                "--json",
            ],  # fmt: skip
            capsys,
        )
        assert code == 0, err
        fit = json.loads(alone)
        assert g["gamma"]["loss"] == fit["loss"] == "l1"
        assert g["gamma"]["coefficients"] == pytest.approx(fit["coefficients"], abs=1e-9, rel=0)
    # with the default of 3 logs a group, two logs each are too few: reported, not fitted, and
    # nothing fitted is exit 1 (tests/test_fleet_ways_out.py)
    code, stdout, _ = run_cli(["fleet", "gamma", str(out)], capsys)
    assert code == 1
    assert stdout.count("too small: 2 logs") == 4 and "0 of 4 groups fitted" in stdout
    assert (out / "fleet-report.html").is_file()


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_a_fifo_never_blocks_the_fleet(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    logs = tmp_path / "logs"
    logs.mkdir()
    os.mkfifo(logs / "pipe.ulg")  # opening it for reading would wait for a writer forever
    (logs / "empty.bin").write_bytes(b"")
    out = tmp_path / "out"
    code, _, err = run_cli(
        ["fleet", "extract", str(logs), "-o", str(out), "--mass-kg", "1", "--workers", "0"], capsys
    )
    assert code == 0, err
    assert [Path(o.path).name for o in read_table(out / "fleet.parquet")] == ["empty.bin"]
    code, _, err = run_cli(
        [
            "fleet",
            "extract",
            str(logs / "pipe.ulg"),
            "-o",
            str(out),
            "--mass-kg",
            "1",
            "--workers",
            "0",
        ],  # fmt: skip
        capsys,
    )
    assert code == 0, err
    (o,) = read_table(out / "fleet.parquet")
    assert o.status == "refused" and "not a regular file" in o.reason


def test_without_the_fleet_extra_the_command_says_how_to_get_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "pyarrow" else real(name, *a)
    )
    code, _, err = run_cli(["fleet", "extract", str(tmp_path), "-o", str(tmp_path / "o")], capsys)
    assert code == 2
    assert err.strip() == "error: thrustmap fleet needs pyarrow: pip install 'thrustmap[fleet]'"


def test_a_stop_signal_inside_a_dask_call_waits_for_the_call_to_return() -> None:
    """A Ctrl-C landing inside client.submit left a half-built future whose collection printed a
    traceback after 'interrupted'. Inside ``signals_held`` the signal is held, then delivered."""
    import signal

    from thrustmap.fleet.run import signals_held

    steps: list[str] = []
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            with signals_held():
                os.kill(os.getpid(), signal.SIGINT)
                steps.append("the call finished")  # not cut short
            steps.append("after the block")  # never reached: delivered on leaving
        assert steps == ["the call finished"]
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        # a signal the process ignores stays ignored
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        with signals_held():
            os.kill(os.getpid(), signal.SIGINT)
        assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, previous)


def test_fleet_gamma_refuses_what_gamma_fit_refuses(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A group whose γ leaves the physical band 0.5..2 gets no γ(B) and no corrected map, with
    the reason `gamma fit` gives for the same Df files (which refuses them, exit 2)."""
    import json

    from support.fleet_gen import AIRFRAMES, Airframe

    odd = Airframe("odd", "dataflash", 1.1, (2.6,))  # thrust 2.6 x what the map predicts
    fleet = make_fleet(tmp_path, 3, airframes=(AIRFRAMES[2], odd), corrupt=False, no_mass=0)
    out = tmp_path / "out"
    assert run_cli(extract_args(fleet, out), capsys)[0] == 0
    code, stdout, err = run_cli(
        ["fleet", "gamma", str(out), "--map", str(fleet.stand_map), "--json"], capsys
    )
    assert code == 0, err
    groups = {g["airframe"]["mass_kg"]: g for g in json.loads(stdout)}
    assert groups[1.2]["status"] == "fitted"
    bad = groups[1.1]
    assert bad["status"] == "refused" and "gamma" not in bad
    assert bad["reason"].startswith("γ(B) reaches 2.5") and "0.5..2" in bad["reason"]
    assert bad["reason"].endswith("(as `gamma fit` refuses it: no corrected map)")
    assert not (out / "gamma" / f"{bad['key']}.map.json").exists()
    assert (out / "gamma" / f"{groups[1.2]['key']}.map.json").is_file()
    code, _, err = run_cli(
        ["gamma", "fit", *bad["df"], "--map", str(fleet.stand_map), "-o", str(tmp_path / "g.json")],
        capsys,
    )
    assert code == 2
    assert bad["reason"].split(" (as `gamma fit`")[0] in err


def test_the_table_is_written_and_read_without_pandas_in_the_same_bytes(tmp_path: Path) -> None:
    """pyarrow's from_pylist/pa.array/read_table import pandas (0.2-0.35 s of every fleet run);
    the table is built from its buffers instead, byte for byte the Parquet from_pylist gives."""
    import subprocess
    import sys

    import pyarrow as pa
    import pyarrow.parquet as pq

    from thrustmap.fleet.table import _schema, write_table

    outcomes = [
        Outcome(path="/a/ü.bin", status="ok", samples=12, dropped_s={"tilt": 1.5, "armed": 0.25},
                warnings=["w1", "ωw2"], mass_kg=1.2, voltage_min_v=22.1, voltage_max_v=24.0,
                flights=2, rotors=4, seconds=0.01, reused=True, airframe='{"x": 1}'),
        Outcome(path="/a/b.ulg", reason="refused: ünïcode", mtime_ns=2**62, size_bytes=7),
        Outcome(path=""),
    ]  # fmt: skip
    ours = tmp_path / "ours.parquet"
    write_table(outcomes, ours)
    rows = [o.to_dict() for o in sorted(outcomes, key=lambda o: o.path)]
    for r in rows:
        r["dropped_s"] = sorted(r["dropped_s"].items())
    sink = pa.BufferOutputStream()
    pq.write_table(pa.Table.from_pylist(rows, schema=_schema()), sink, compression="zstd")
    assert ours.read_bytes() == sink.getvalue().to_pybytes()
    import json

    def plain(o: Outcome) -> object:  # NaN == NaN
        return json.loads(json.dumps(o.to_dict()).replace("NaN", "null"))

    assert [plain(o) for o in read_table(ours)] == [
        plain(o) for o in sorted(outcomes, key=lambda o: o.path)
    ]
    code = (
        "import sys\n"
        "from thrustmap.fleet.table import read_table, write_table\n"
        f"write_table(read_table({str(ours)!r}), {str(tmp_path / 'again.parquet')!r})\n"
        "assert 'pandas' not in sys.modules, 'pandas imported'\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "again.parquet").read_bytes() == ours.read_bytes()
