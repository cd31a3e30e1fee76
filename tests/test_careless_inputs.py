"""Careless inputs (issue 31): each row is a command, its input, the exit code it must end with
and a phrase of the line it must say. No row may produce a traceback or an "internal error",
and none may answer with exit 0 what the same tool refuses elsewhere.

The rows cover the sixteen cases of issue 31 that are this branch's (items 5 and 6 belong to
the interval work, 10 and 15 to the fleet work) and the careless inputs the README's tour
invites: typos, units (millivolts, grams, kilograms), ranges, missing answers. Every command
runs in-process through :func:`thrustmap.cli.main` (the one place exit codes are decided), on
the project's own fixtures and on small files written here.
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from support.terminal import DemoRun

from thrustmap.cli import main

FIXTURES = Path(__file__).resolve().parent.parent / "fixtures"
FL = FIXTURES / "flightlogs"


@dataclass(frozen=True)
class Row:
    name: str
    argv: str  # split on spaces ("~" is a space inside one argument); {map} {tmp} {ulg} {run}
    code: int
    phrase: str  # in stdout or stderr
    stdin: str | None = None  # None: no terminal and nothing to read (stdin at EOF)
    absent: str | None = None  # text that must NOT appear (e.g. "spinning" before a refusal)


# -- the workspace the rows run in -----------------------------------------------------------


def _step_summary(path: Path, voltage_v: float, *, header_thrust: str = "Thrust (gf)") -> None:
    """An RCbenchmark-style step summary (one averaged row per step, 1050..2000 µs), grams of
    thrust and amperes of current as a 5-inch motor makes them (about 4 gf/W)."""
    lines = [f"Time (s),ESC signal (µs),{header_thrust},Voltage (V),Current (A)"]
    for k in range(11):
        us = 1050 + 95 * k
        x = (us - 1000) / 1000.0
        thrust_gf = 15.0 + 900.0 * x**2 * voltage_v / 11.1
        sag_v = voltage_v - 0.01 * k
        current_a = thrust_gf / 4.0 / sag_v
        lines.append(f"{2.0 * k:.1f},{us},{thrust_gf:.3f},{sag_v:.3f},{current_a:.3f}")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    tmp = tmp_path_factory.mktemp("careless")
    shutil.copy(FL / "sim_map.json", tmp / "map.json")
    doc = json.loads((FL / "sim_map.json").read_text())
    neg = dict(doc, coefficients=[doc["coefficients"][0], 0.0, -512.0, doc["coefficients"][3]])
    (tmp / "neg.json").write_text(json.dumps(neg))
    off = dict(doc, correction={"coefficients": [0.00114], "voltage_v": [21.0, 24.0]})
    (tmp / "gamma_off.json").write_text(json.dumps(off))
    (tmp / "truncated.json").write_text((FL / "sim_map.json").read_text()[:200])
    (tmp / "empty.csv").write_text("")
    (tmp / "picture.png").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4)
    _step_summary(tmp / "s_7.csv", 7.4)
    _step_summary(tmp / "s_11.csv", 11.1)
    # grams under a header that says so, read as newtons
    _step_summary(tmp / "grams_header.csv", 11.1)
    # grams under a header without a unit, a current column the column map does not name
    _step_summary(tmp / "grams_plain.csv", 11.1, header_thrust="Thrust")
    # a Df of a vehicle whose mass was typed in grams (no map to question it), a too-short one
    ulg = str(FL / "sim_hover.ulg")
    for argv in (
        ["flightlog", "extract", ulg, "--mass-kg", "1200", "-o", str(tmp / "heavy.csv")],
        ["flightlog", "extract", ulg, "--mass-kg", "1", "--rate-hz", "2",
         "-o", str(tmp / "short.csv")],
        ["flightlog", "extract", ulg, "--mass-kg", "1", "-o", str(tmp / "df.csv")],
    ):  # fmt: skip
        assert _run(argv)[0] == 0
    return {
        "tmp": str(tmp),
        "map": str(tmp / "map.json"),
        "ulg": ulg,
        "run": str(FIXTURES / "sweeps" / "msp_run.csv"),
    }


def _run(argv: list[str], stdin: str | None = None) -> tuple[int, str, str]:
    """``thrustmap ARGV`` in-process: (exit code, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    old = sys.stdout, sys.stderr, sys.stdin
    sys.stdout, sys.stderr, sys.stdin = out, err, io.StringIO(stdin or "")
    try:
        try:
            main(argv)
            code = 0
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    finally:
        sys.stdout, sys.stderr, sys.stdin = old
    return code, out.getvalue(), err.getvalue()


ROWS = [
    # --- issue 31, wrong answers -------------------------------------------------------------
    Row(
        "1 predict at 1000 V",
        "predict {map} --thrust-n 4 --voltage-v 1000",
        2,
        "is not a battery voltage",
    ),
    Row(
        "1 predict in millivolts",
        "predict {map} --thrust-n 4 --voltage-v 24000",
        2,
        "millivolts? 24 V",
    ),
    Row("1 predict below 1S", "predict {map} --thrust-n 4 --voltage-v 1", 2, "expected 2.5..63 V"),
    Row(
        "2 grams typed as newtons (header says gf)",
        "fit {tmp}/grams_header.csv --col-throttle ESC~signal~(µs) --col-thrust Thrust~(gf) "
        "--col-voltage Voltage~(V) --thrust-unit N -o {tmp}/g1.json",
        2,
        "--thrust-unit gf",
    ),
    Row(
        "2 grams typed as newtons (current in the file)",
        "fit {tmp}/grams_plain.csv --col-throttle ESC~signal~(µs) --col-thrust Thrust "
        "--col-voltage Voltage~(V) --thrust-unit N -o {tmp}/g2.json",
        2,
        "gf/W",
    ),
    Row(
        "2 predict at grams typed as newtons",
        "predict {map} --thrust-n 5000 --voltage-v 24",
        2,
        "grams typed as newtons",
    ),
    Row(
        "3 mass typed in grams",
        "flightlog extract {ulg} --mass-kg 1200 --map {map} -o {tmp}/x1.csv",
        2,
        "grams typed as kilograms",
    ),
    Row(
        "3 gamma far outside 0.5..2",
        "gamma fit {tmp}/heavy.csv --map {map} -o {tmp}/x2.json",
        2,
        "agree within 0.5..2",
    ),
    Row(
        "3 a map holding such a gamma",
        "predict {tmp}/gamma_off.json --thrust-n 2 --voltage-v 22",
        2,
        "not written with --force",
    ),
    Row(
        "3 export with the mass in grams",
        "export {map} --to px4 --mass-kg 1200",
        2,
        "grams typed as kilograms",
    ),
    Row(
        "4 hand-edited k1 < 0",
        "predict {tmp}/neg.json --thrust-n 4 --voltage-v 24",
        2,
        "needs it >= 0",
    ),
    Row(
        "7 gamma on a too-short Df",
        "gamma fit {tmp}/short.csv --map {map} -o {tmp}/x3.json",
        2,
        "too short for a γ fit",
    ),
    # --- issue 31, ways out ------------------------------------------------------------------
    Row(
        "11 a motor the FC does not have",
        "spin sim://betaflight --motor 9 --throttle 10 --yes",
        2,
        "motor 9 does not exist",
        absent="spinning",
    ),
    Row(
        "12 no terminal to ask",
        "spin sim://betaflight --motor 1 --throttle 10",
        2,
        "--yes confirms",
        absent="aborted",
    ),
    Row(
        "12 sweep with no terminal to ask",
        "sweep steps --stand sim://tyto-1585 --throttle sim://betaflight -o {tmp}/sw1.csv",
        2,
        "--yes confirms",
        absent="aborted",
    ),
    Row(
        "12 answered no",
        "spin sim://betaflight --motor 1 --throttle 10",
        2,
        "nothing spun",
        stdin="n\n",
    ),
    Row(
        "13 a level that is not a number",
        "sweep explicit --stand sim://tyto-1585 --levels 10,abc -o {tmp}/sw2.csv --dry-run",
        2,
        "'abc' is not a number",
    ),
    Row(
        "13 a level above 100 %",
        "sweep explicit --stand sim://tyto-1585 --levels 10,200 -o {tmp}/sw3.csv --dry-run",
        2,
        "expected 0..100 %",
    ),
    Row(
        "14 a model that cannot be fitted on a fold",
        "compare {tmp}/s_7.csv {tmp}/s_11.csv --models motor,linear,poly4 --validate by-file",
        0,
        "not fitted: poly4 by-file fold",
    ),
    Row(
        "14 no model can be fitted",
        "compare {tmp}/s_7.csv {tmp}/s_11.csv --models poly4 --validate by-file",
        2,
        "no model could be fitted",
    ),
    Row(
        "16 rate_hz=0",
        "spin sim://betaflight?rate_hz=0 --motor 1 --throttle 10 --yes",
        2,
        "sim option rate_hz='0'",
    ),
    Row(
        "16 rate_hz=-5",
        "spin sim://betaflight?rate_hz=-5 --motor 1 --throttle 10 --yes",
        2,
        "sim option rate_hz='-5'",
    ),
    Row(
        "16 drive_esc=maybe",
        "probe sim://tyto-1585?drive_esc=maybe",
        2,
        "sim option drive_esc='maybe'",
    ),
    Row(
        "16 motors=400 names motors",
        "spin sim://px4?motors=400 --motor 1 --throttle 10 --yes",
        2,
        "sim option motors='400'",
    ),
    Row(
        "16 PX4 telemetry rate 0",
        "spin sim://px4?rate_hz=0 --motor 1 --throttle 10 --yes",
        2,
        "sim option rate_hz='0'",
    ),
    Row("16 a negative boot time", "probe sim://tyto-1585?boot_s=-1", 2, "boot_s='-1'"),
    # --- the README tour, carelessly ---------------------------------------------------------
    Row("a file that is not there", "fit {tmp}/nothere.csv -o {tmp}/m.json", 2, "nothere.csv"),
    Row("a folder for a file", "fit {tmp} -o {tmp}/m.json", 2, "is a directory"),
    Row("an empty stand log", "fit {tmp}/empty.csv -o {tmp}/m.json", 2, "empty.csv"),
    Row("a picture for a stand log", "fit {tmp}/picture.png -o {tmp}/m.json", 2, "picture.png"),
    Row("a model name typo", "fit {run} --model poyl2 -o {tmp}/m.json", 2, "poyl2"),
    Row("a reversed range", "fit {run} --voltage-range 30:20 -o {tmp}/m.json", 2, "LO < HI"),
    Row(
        "a scale option without a column map",
        "fit {run} --throttle-scale pwn -o {tmp}/m.json",
        2,
        "applies only with a column map",
    ),
    Row(
        "an unknown throttle scale",
        "fit {tmp}/grams_plain.csv --col-throttle ESC~signal~(µs) "
        "--col-thrust Thrust --col-voltage Voltage~(V) --throttle-scale pwn -o {tmp}/m.json",
        2,
        "unknown throttle scale 'pwn'",
    ),
    Row("predict without a voltage", "predict {map} --thrust-n 4", 2, "--voltage-v"),
    Row("predict a negative thrust", "predict {map} --thrust-n -1 --voltage-v 24", 2, ">= 0"),
    Row("predict NaN", "predict {map} --thrust-n nan --voltage-v 24", 2, "finite"),
    Row(
        "predict both directions",
        "predict {map} --thrust-n 4 --throttle-pct 50 --voltage-v 24",
        2,
        "exactly one",
    ),
    Row("predict 150 %", "predict {map} --throttle-pct 150 --voltage-v 24", 2, "0..100 %"),
    Row(  # issue 44 item 12: zero thrust is the spin-up, not "unreachable"
        "predict zero thrust",
        "predict {map} --thrust-n 0 --voltage-v 24",
        0,
        "zero thrust at 24.00 V",
        absent="unreachable",
    ),
    Row(
        "predict more than the motor makes",
        "predict {map} --thrust-n 100 --voltage-v 24",
        1,
        "unreachable",
    ),
    Row(
        "a truncated map",
        "predict {tmp}/truncated.json --thrust-n 4 --voltage-v 24",
        2,
        "truncated.json",
    ),
    Row("a stand log for a map", "predict {run} --thrust-n 4 --voltage-v 24", 2, "msp_run.csv"),
    Row("export in millivolts", "export {map} --to px4 --voltage-v 24000", 2, "millivolts"),
    Row("export a negative mass", "export {map} --to px4 --mass-kg -1", 2, "positive"),
    Row("extract without a mass", "flightlog extract {ulg} -o {tmp}/x4.csv", 2, "--mass-kg"),
    Row(
        "extract a negative mass",
        "flightlog extract {ulg} --mass-kg -1 -o {tmp}/x5.csv",
        2,
        "mass must be positive",
    ),
    Row(
        "extract at 0 Hz",
        "flightlog extract {ulg} --mass-kg 1 --rate-hz 0 -o {tmp}/x6.csv",
        2,
        "--rate-hz 0: expected 0.5..1000 Hz",
    ),
    Row(
        "gamma on a Df that is not there",
        "gamma fit {tmp}/nodf.csv --map {map} -o {tmp}/x7.json",
        2,
        "nodf.csv",
    ),
    Row("spin at motor 0", "spin sim://betaflight --motor 0 --throttle 10 --yes", 2, "1..16"),
    Row(
        "spin above the cap",
        "spin sim://betaflight --motor 1 --throttle 50 --yes",
        2,
        "--max-throttle 50",
    ),
    Row(
        "spin for minutes",
        "spin sim://betaflight --motor 1 --throttle 10 --seconds 100 --yes",
        2,
        "at most 10 s",
    ),
    Row(
        "a sweep with a negative dwell",
        "sweep steps --stand sim://tyto-1585 --dwell -1 -o {tmp}/sw4.csv --dry-run",
        2,
        "dwell",
    ),
    Row(
        "a negative current limit",
        "sweep steps --stand sim://tyto-1585 --max-current -5 -o {tmp}/sw5.csv --dry-run",
        2,
        "--max-current -5: expected a number > 0",
    ),
    Row(
        "a tilt beyond 90 degrees",
        "flightlog extract {ulg} --mass-kg 1 --tilt-max-deg 500 -o {tmp}/x8.csv",
        2,
        "--tilt-max-deg 500: expected 1..90 deg",
    ),
    Row(
        "a negative hover tolerance",
        "flightlog extract {ulg} --mass-kg 1 --accel-tol -1 -o {tmp}/x9.csv",
        2,
        "--accel-tol -1",
    ),
    Row(
        "gamma with -1 rotors",
        "gamma fit {tmp}/df.csv --map {map} --rotors -1 -o {tmp}/x10.json",
        2,
        "--rotors -1",
    ),
    Row(
        "a pack voltage for the per-cell limit",
        "sweep steps --stand sim://tyto-1585 --min-cell-voltage 22.2 -o {tmp}/sw6.csv --dry-run",
        2,
        "it is per cell",
    ),
    Row(
        "a sweep repeated 0 times",
        "sweep steps --stand sim://tyto-1585 --repeats 0 -o {tmp}/sw7.csv --dry-run",
        2,
        "--repeats 0: expected 1 or more",
    ),
    Row(
        "a spin of 0 s",
        "spin sim://betaflight --motor 1 --throttle 10 --seconds 0 --yes",
        2,
        "--seconds 0: expected a positive duration",
    ),
    Row("a command typo", "fti {run}", 2, "No such command"),
    # -- issue 44, bench side: never past what was asked, every role checked first ----------
    Row(
        "44.1 stairs --to 60 --step 20 ends at 60, not 70",
        "sweep stairs-up --stand sim://tyto-1585 --throttle sim://betaflight --to 60 --step 20 "
        "--dwell 1 --dry-run -o {tmp}/c44a.csv",
        0,
        "ceiling 60.0 %",
        absent="70.0 %",
    ),
    Row(
        "44.1 --step 100 within --to 60",
        "sweep stairs-up --stand sim://tyto-1585 --throttle sim://betaflight --to 60 --step 100 "
        "--dwell 1 --dry-run -o {tmp}/c44b.csv",
        0,
        "ceiling 60.0 %",
        absent="110",
    ),
    Row(
        "44.1 steps returning above --to",
        "sweep steps --stand sim://tyto-1585 --from 2 --to 5 --step 1 --dry-run -o {tmp}/c44c.csv",
        2,
        "--low 10 % is above --to 5 %",
    ),
    Row(
        "44.6 a stand given as the throttle",
        "sweep stairs-up --stand sim://tyto-1585 --throttle sim://line-stand --to 30 --dwell 1 "
        "--yes -o {tmp}/c44d.csv",
        2,
        "is a thrust stand, not a flight controller",
        absent="thrown propeller",
    ),
    Row(
        "44.6 the stand given twice",
        "sweep stairs-up --stand sim://tyto-1585 --throttle sim://tyto-1585 --to 30 --dwell 1 "
        "--yes -o {tmp}/c44e.csv",
        2,
        "not a flight controller",
        absent="thrown propeller",
    ),
    Row(
        "44.12 spin --throttle 0.5 meant as 50 %",
        "spin sim://betaflight --motor 1 --throttle 0.5 --yes",
        2,
        "did you mean 50 %?",
        absent="spinning",
    ),
    Row(
        "44.12 probe names no test file",
        "probe sim://betaflight",
        0,
        "against real Betaflight 4.6.0 SITL",
        absent="tests/",
    ),
    # --- issue 44 items 5 and 8: a voltage that is one cell, a map for another platform -------
    Row(
        "44.5 predict at one cell of a 6S map",
        "predict {map} --thrust-n 4 --voltage-v 4.1",
        2,
        "is one cell of the map's 6S pack",
    ),
    Row(
        "44.8 a 6S map exported to the 1S Crazyflie",
        "export {map} --to crazyflie -o {tmp}/cf.yaml",
        2,
        "measured on a 6S pack (20.40..25.20 V) but crazyflie flies on 1S",
    ),
]


def _argv(row: Row, work: dict[str, str]) -> list[str]:
    return [part.replace("~", " ") for part in row.argv.format(**work).split(" ")]


@pytest.mark.parametrize("row", ROWS, ids=[r.name for r in ROWS])
def test_careless_input(row: Row, work: dict[str, str]) -> None:
    code, out, err = _run(_argv(row, work), row.stdin)
    text = out + err
    assert "Traceback" not in text and "internal error" not in text, text
    assert code == row.code, f"exit {code}, expected {row.code}:\n{text}"
    assert row.phrase in text, text
    if row.absent is not None:
        assert row.absent not in text, text
    if code == 2:  # a refusal is one line naming what was expected
        lines = [ln for ln in err.splitlines() if ln.startswith("error:")]
        assert len(lines) == 1, err


def test_at_least_forty_rows() -> None:
    assert len(ROWS) >= 40


def test_forced_gamma_is_said_and_recorded(work: dict[str, str]) -> None:
    """--force writes the refused γ, says so, records it in the map; predict says γ applied."""
    out_map = Path(work["tmp"]) / "forced.json"
    code, _, err = _run(
        ["gamma", "fit", f"{work['tmp']}/heavy.csv", "--map", work["map"], "-o", str(out_map),
         "--force"]
    )  # fmt: skip
    assert code == 0 and "forced (--force), recorded in the map" in err
    forced = json.loads(out_map.read_text())["correction"]["metrics"]["forced"]
    assert any("0.5..2" in f for f in forced)
    code, out, _ = _run(["predict", str(out_map), "--thrust-n", "2", "--voltage-v", "22"])
    assert code == 0 and "flight correction applied" in out and "--force" in out


def test_predict_says_gamma_applied(work: dict[str, str]) -> None:
    out_map = Path(work["tmp"]) / "good.json"
    code, _, err = _run(
        ["gamma", "fit", f"{work['tmp']}/df.csv", "--map", work["map"], "-o", str(out_map)]
    )
    assert code == 0, err
    code, out, _ = _run(["predict", str(out_map), "--thrust-n", "2", "--voltage-v", "22"])
    assert code == 0 and "flight correction applied: γ(B) = " in out
    gamma = float(out.split("γ(B) = ")[1].split()[0])
    assert 0.5 <= gamma <= 2.0
    code, out, _ = _run(["predict", str(out_map), "--thrust-n", "2", "--voltage-v", "22", "--json"])
    assert json.loads(out)["gamma"] == pytest.approx(gamma, rel=1e-3)
    code, out, _ = _run(
        ["predict", str(out_map), "--thrust-n", "2", "--voltage-v", "22", "--no-correction"]
    )
    assert code == 0 and "flight correction" not in out


def test_extract_force_records_the_mass_refusal(work: dict[str, str]) -> None:
    out = Path(work["tmp"]) / "forced_df.csv"
    code, _, err = _run(
        ["flightlog", "extract", work["ulg"], "--mass-kg", "1200", "--map", work["map"],
         "--force", "-o", str(out)]
    )  # fmt: skip
    assert code == 0 and "forced (--force), recorded in the Df sidecar" in err
    side = json.loads(out.with_suffix(".json").read_text())
    assert any("grams typed as kilograms" in f for f in side["forced"])


@pytest.mark.parametrize("parallel", [False, True], ids=["serial", "forked-workers"])
def test_demo_ctrl_c_stops_with_130_and_no_report(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, parallel: bool
) -> None:
    """Ctrl-C during a simulated sweep (the runner reports it as an interrupted run) stops the
    demo: exit 130, no map fitted on the partial data, no report; in this process or in the
    forked worker per strategy that the CLI uses on two cores."""
    import thrustmap.demo as demo
    from thrustmap.rig.run_types import RunResult

    calls = []

    def interrupted(*args: object, **kwargs: object) -> RunResult:
        calls.append(args)
        return RunResult("aborted", "interrupted (Ctrl-C)", 0, 0.1, True, None, interrupted=True)

    monkeypatch.setattr(demo, "record_sweep", interrupted)
    monkeypatch.setattr(demo, "_parallel_ok", lambda: parallel)
    code, out, err = _run(["demo", "-q", "-o", str(tmp_path / "d")])
    assert code == 130, out + err
    if not parallel:  # (a forked worker's calls are counted in its own memory)
        assert len(calls) == 1  # nothing after the interrupted sweep
    assert "interrupted" in err and "no report written" in err
    written = [p for p in (tmp_path / "d").rglob("*.json") if p.name != "thrustmap-demo.json"]
    assert not written and not list((tmp_path / "d").rglob("*.html"))  # (the manifest of its
    # own files, which lets a re-run replace them, is not a result)
    assert out == ""  # nothing presented as complete


def test_accelerometer_in_g_is_caught(work: dict[str, str]) -> None:
    """A binary log's acceleration in g (≈ 1 at hover) is converted and said, not used as
    m/s² (which leaves no sample near hover, or a force ten times too small)."""
    from thrustmap.fitting.df.extraction import extract
    from thrustmap.fitting.df_options import DfOptions
    from thrustmap.fitting.mapfile import ThrustMap
    from thrustmap.flightlogs.detect import read_log

    (flight,) = read_log(Path(work["ulg"]))
    acc = flight.accel_up_mps2
    assert acc is not None
    in_g = dataclasses.replace(
        flight, accel_up_mps2=dataclasses.replace(acc, values=acc.values / 9.80665)
    )
    tmap = ThrustMap.load(work["map"])
    ref = extract([flight], DfOptions(mass_kg=1.0), tmap)
    got = extract([in_g], DfOptions(mass_kg=1.0), tmap)
    assert len(got) == len(ref) > 0
    assert math.isclose(
        float(got.table["force_n"].median()), float(ref.table["force_n"].median()), rel_tol=1e-6
    )
    notes = [w for r in got.reports for w in r.warnings]
    assert any("taken as g" in w for w in notes), notes


def test_ctrl_c_at_the_safety_question(monkeypatch: pytest.MonkeyPatch) -> None:
    """Ctrl-C while the question waits: exit 130 (an interruption, not a refusal), nothing
    spun and said so."""

    class CtrlC(io.StringIO):
        def readline(self, size: int | None = -1) -> str:
            raise KeyboardInterrupt

    out, err = io.StringIO(), io.StringIO()
    monkeypatch.setattr(sys, "stdin", CtrlC())
    monkeypatch.setattr(sys, "stdout", out)
    monkeypatch.setattr(sys, "stderr", err)
    with pytest.raises(SystemExit) as exc:
        main(["spin", "sim://betaflight", "--motor", "1", "--throttle", "10"])
    assert exc.value.code == 130
    assert "interrupted: at the safety question: nothing spun" in err.getvalue()
    assert "spinning" not in out.getvalue()


def test_grams_as_newtons_on_real_stand_logs(shared_data: Path, tmp_path: Path) -> None:
    """Every Strawson 5-inch file (96 motor × propeller × voltage step summaries, not ours):
    its own unit loads; the same file under a unitless thrust header read as newtons — the
    column map naming no current column — is refused, at any number of its first rows from 4."""
    from thrustmap.core.errors import DataFormatError
    from thrustmap.core.units import SCALES
    from thrustmap.fitting.loaders.load import ColumnMap, load_dataset

    files = sorted((shared_data / "third-party-stands" / "strawson-5inch").glob("*.csv"))
    assert len(files) == 96
    as_newtons = ColumnMap(
        "ESC signal (µs)", "Thrust", "Voltage (V)", thrust_unit="N", throttle_scale=SCALES["pwm"]
    )
    for path in files:
        load_dataset(path)  # no false refusal
        lines = path.read_text(encoding="utf-8-sig").splitlines()
        head = lines[0].replace("Thrust (gf)", "Thrust")
        for rows in (4, len(lines) - 1):
            bad = tmp_path / f"{rows}_{path.name}"
            bad.write_text("\n".join([head, *lines[1 : rows + 1]]) + "\n", encoding="utf-8")
            with pytest.raises(DataFormatError, match="gf/W"):
                load_dataset(bad, as_newtons)


# --- issue 44 (branch careless): inputs counted twice, another map, units by physics ----------
# (rows for items 1, 6 and 12's spin/probe are the coordinator's, in a block of their own)


def _stand_summary(
    path: Path, voltage_v: float, *, header: str, thrust_div: float = 1.0,
    cells: int = 1, current: bool = True,
) -> None:  # fmt: skip
    """A step summary as `_step_summary` writes it, with the thrust divided by ``thrust_div``
    (1000: kgf in a column that says nothing), the voltage column divided by ``cells`` (a
    per-cell column) and the current column optional."""
    head = f"Time (s),ESC signal (µs),{header},Voltage (V)" + (",Current (A)" if current else "")
    lines = [head]
    for k in range(11):
        us = 1050 + 95 * k
        x = (us - 1000) / 1000.0
        thrust_gf = 15.0 + 900.0 * x**2 * voltage_v / 11.1
        sag_v = voltage_v - 0.01 * k
        row = f"{2.0 * k:.1f},{us},{thrust_gf / thrust_div:.5f},{sag_v / cells:.4f}"
        lines.append(row + (f",{thrust_gf / 4.0 / sag_v:.3f}" if current else ""))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


@pytest.fixture(scope="module")
def work44(work: dict[str, str]) -> dict[str, str]:
    tmp = Path(work["tmp"]) / "i44"
    tmp.mkdir()
    doc = json.loads((FL / "sim_map.json").read_text())
    other = dict(doc, coefficients=[doc["coefficients"][0], doc["coefficients"][1] * 1.1,
                                    *doc["coefficients"][2:]])  # fmt: skip
    (tmp / "other.json").write_text(json.dumps(other))
    shutil.copy(work["run"], tmp / "copy.csv")
    for kg in ("1.5", "1.4"):  # the same flight extracted twice, at two masses
        code, _, err = _run(["flightlog", "extract", work["ulg"], "--mass-kg", kg, "--map",
                             work["map"], "-o", str(tmp / f"d{kg}.csv")])  # fmt: skip
        assert code == 0, err
    _stand_summary(tmp / "kgf_current.csv", 16.0, header="Thrust", thrust_div=1000.0)
    _stand_summary(tmp / "kgf_alone.csv", 16.0, header="Thrust", thrust_div=1000.0, current=False)
    _stand_summary(tmp / "cell_current.csv", 24.6, header="Thrust (gf)", cells=6)
    _stand_summary(tmp / "cell_alone.csv", 24.6, header="Thrust (gf)", cells=6, current=False)
    _stand_summary(tmp / "one_cell.csv", 4.1, header="Thrust (gf)", current=False)
    # item 7: a map fitted on two voltages, and a log of another rig
    assert _run(["fit", work["tmp"] + "/s_7.csv", work["tmp"] + "/s_11.csv",
                 "-o", str(tmp / "m711.json")])[0] == 0  # fmt: skip
    _step_summary(tmp / "other_rig.csv", 8.4)
    # item 10: a data folder as the demo leaves it: Ds logs with their sidecars
    (tmp / "sr").mkdir()
    for name in ("msp_run.csv", "msp_run.meta.json"):
        shutil.copy(FIXTURES / "sweeps" / name, tmp / "sr" / name)
    (tmp / "empty").mkdir()
    return {**work, "i44": str(tmp), "fl": str(FL)}


_COLS = "--col-throttle ESC~signal~(µs) --col-thrust Thrust --col-voltage Voltage~(V)"

ROWS_44 = [
    Row("44.2 a stand log twice", "fit {run} {run} -o {i44}/m.json", 2, "are the same file"),
    Row(
        "44.2 a stand log and its copy",
        "compare {run} {i44}/copy.csv",
        2,
        "are the same content",
    ),
    Row(
        "44.2 a report over a log twice",
        "report {map} {run} {run} -o {i44}/r.html",
        2,
        "are the same file",
    ),
    Row(
        "44.2 a Df twice",
        "gamma fit {i44}/d1.5.csv {i44}/d1.5.csv --map {map} -o {i44}/g.json",
        2,
        "are the same file",
    ),  # fmt: skip
    Row(
        "44.2 one flight extracted at two masses",
        "gamma fit {i44}/d1.5.csv {i44}/d1.4.csv --map {map} -o {i44}/g.json",
        2,
        "are the same flight",
        absent="different masses",
    ),
    Row(
        "44.2 a flight log twice",
        "flightlog extract {ulg} {ulg} --mass-kg 1 -o {i44}/x.csv",
        2,
        "are the same file",
    ),
    Row(
        "44.3 gamma against another map",
        "gamma fit {i44}/d1.5.csv --map {i44}/other.json -o {i44}/g.json",
        2,
        "not with",
    ),
    Row(
        "44.4 kgf in a unitless column, current beside it",
        "fit {i44}/kgf_current.csv " + _COLS + " -o {i44}/m.json",
        2,
        "--thrust-unit kgf",
    ),
    Row(
        "44.4 kgf in a unitless column, no current",
        "fit {i44}/kgf_alone.csv " + _COLS + " -o {i44}/m.json",
        2,
        "--thrust-unit kgf",
    ),
    Row(
        "44.5 a per-cell voltage beside a current",
        "fit {i44}/cell_current.csv -o {i44}/m.json",
        2,
        "per cell of a bigger pack",
    ),
    Row(
        "44.5 a per-cell voltage, no current",
        "fit {i44}/cell_alone.csv -o {i44}/m.json",
        2,
        "per cell of a bigger pack",
    ),
    Row(
        "44.5 a 1S pack is said",
        "fit {i44}/one_cell.csv -o {i44}/m.json",
        0,
        "the pack is taken as 1S",
    ),
    Row(
        "44.7 a report on another rig's data",
        "report {i44}/m711.json {i44}/other_rig.csv -o {i44}/r.html",
        0,
        "not the map's sources",
    ),
    Row(
        "44.10 a data folder's logs and sidecars (fit sr/*)",
        "fit {i44}/sr/msp_run.csv {i44}/sr/msp_run.meta.json -o {i44}/m.json",
        0,
        "wrote",
    ),
    Row(
        "44.10 a sidecar alone as a stand log",
        "fit {i44}/sr/msp_run.meta.json -o {i44}/m.json",
        2,
        "a JSON file",
        absent="single column",
    ),
    Row(
        "44.11 a fleet without a mass",
        "fleet extract {fl} -o {i44}/fleet1 --workers 0 --quiet",
        2,
        "take-off mass",
        absent="refused",
    ),
    Row(
        "44.11 a fleet of an empty folder",
        "fleet extract {i44}/empty --mass-kg 1 -o {i44}/fleet2 --workers 0 --quiet",
        2,
        "no flight log found",
    ),
    Row(
        "44.12 a Df sidecar for the Df",
        "gamma fit {i44}/d1.5.json --map {map} -o {i44}/g.json",
        2,
        "a JSON file",
        absent="tokeniz",
    ),
    Row(
        "44.12 a gamma with a falling slope",
        "gamma fit {i44}/d1.5.csv --map {map} -o {i44}/g.json",
        0,
        "γ(B) = ",
        absent="+ -",
    ),
]


@pytest.mark.parametrize("row", ROWS_44, ids=[r.name for r in ROWS_44])
def test_careless_input_44(row: Row, work44: dict[str, str]) -> None:
    test_careless_input(row, work44)


def test_44_gamma_on_the_map_with_its_own_gamma(work44: dict[str, str]) -> None:
    """A Df extracted with a bench map matches that map once a γ block is attached (the bench
    part is what T_c came through); a Df from before the map was recorded is said unchecked."""
    tmp = Path(work44["i44"])
    first = tmp / "first.json"
    assert _run(["gamma", "fit", str(tmp / "d1.5.csv"), "--map", work44["map"],
                 "-o", str(first)])[0] == 0  # fmt: skip
    code, _, err = _run(["gamma", "fit", str(tmp / "d1.5.csv"), "--map", str(first),
                         "-o", str(tmp / "again.json")])  # fmt: skip
    assert code == 0, err
    old = tmp / "old.csv"
    shutil.copy(tmp / "d1.5.csv", old)
    side = json.loads((tmp / "d1.5.json").read_text())
    del side["map"]
    old.with_suffix(".json").write_text(json.dumps(side))
    code, _, err = _run(["gamma", "fit", str(old), "--map", str(tmp / "other.json"),
                         "-o", str(tmp / "o.json")])  # fmt: skip
    assert code == 0 and "cannot be checked" in err, err


def test_44_paper_csv_in_g_with_a_ground_stretch(tmp_path: Path) -> None:
    """Item 9: a seed-paper flight CSV whose acceleration is in g (≈ 1 in hover) and whose
    long ground stretch is logged as zeros (the log's mean 0.43) is g: converted and said,
    the Df's force the same as the m/s² file's, never g0 added to it."""
    import pandas as pd

    d = pd.read_csv(FL / "sim_hover_paper.csv")
    ground = pd.concat([d.iloc[:1]] * 800, ignore_index=True)
    ground["Time (s)"] = -40.0 + 0.05 * np.arange(800)
    for col in ("Acc (m/s²)", "Position_z (m)", "Throttle (%)", "Thrust sended (N)"):
        ground[col] = 0.0
    in_ms2 = pd.concat([ground, d], ignore_index=True)
    in_ms2.loc[len(ground) :, "Acc (m/s²)"] = d["Acc (m/s²)"].to_numpy()
    in_g = in_ms2.copy()
    in_g["Acc (m/s²)"] = in_g["Acc (m/s²)"] / 9.80665
    assert in_g["Acc (m/s²)"].mean() < 0.5  # what once read as gravity-compensated
    forces = []
    for name, table in (("ms2", in_ms2), ("g", in_g)):
        table.to_csv(tmp_path / f"{name}.csv", index=False)
        code, out, err = _run(["flightlog", "extract", str(tmp_path / f"{name}.csv"),
                               "--mass-kg", "1", "-o", str(tmp_path / f"df_{name}.csv")])  # fmt: skip
        assert code == 0, err
        forces.append(float(pd.read_csv(tmp_path / f"df_{name}.csv")["force_n"].median()))
    assert "taken as g" in out and "g0 added" not in out + err
    assert forces[1] == pytest.approx(forces[0], rel=1e-6)
    assert 9.0 < forces[1] < 10.6


def test_44_no_empty_fleet_table(work44: dict[str, str]) -> None:
    """Item 11: the empty folder's refusal writes nothing (no empty Parquet)."""
    code, _, _ = _run(["fleet", "extract", work44["i44"] + "/empty", "--mass-kg", "1", "-o",
                       work44["i44"] + "/fleet3", "--workers", "0", "--quiet"])  # fmt: skip
    assert code == 2 and not Path(work44["i44"], "fleet3").exists()


def test_44_inspect_names_a_normalised_scale(tmp_path: Path) -> None:
    """Item 12: inspect on a 0..1 throttle scale says "normalised", not "0..1 1"."""
    path = tmp_path / "norm.csv"
    rows = ["thr,Thrust (N),Voltage (V)"]
    rows += [f"{k / 10:.1f},{0.1 + 8 * (k / 10) ** 2:.3f},16.0" for k in range(1, 11)]
    path.write_text("\n".join(rows) + "\n")
    code, out, err = _run(["inspect", str(path), "--col-throttle", "thr", "--col-thrust",
                           "Thrust (N)", "--col-voltage", "Voltage (V)", "--throttle-scale",
                           "norm"])  # fmt: skip
    assert code == 0, err
    assert "norm 0..1 (normalised)" in out and "0..1 1" not in out


def test_44_plateaus_weigh_for_their_file_and_held_out_error_shows_why(
    shared_data: Path, tmp_path: Path
) -> None:
    """Item 14: a ramp's dense samples in one file no longer shrink another file's plateaus to
    one sample's worth each (xNova SR: 29 plateaus carried 3 %, the demo's 44 carried 0 %):
    each file counts for the command range it covers. Held out by file (every held-out point)
    the map is better than with the cells pooled over files: 0.655 % against 0.703 %
    (benchmarks/bench_weighting.py); the steps + steps-up pair stays at 0.599 %."""
    from thrustmap.fitting.fit.coefficients import fit_coefficients, pool
    from thrustmap.fitting.fit.validation import compare
    from thrustmap.fitting.loaders.load import load_datasets
    from thrustmap.fitting.models import MODELS
    from thrustmap.fitting.selection.options import Selection

    sr = shared_data / "xnova-thrust-stand" / "single_rotor"
    files = [str(sr / f"xNova-SR-{n}.csv") for n in ("ramp", "steps", "steps-up")]
    code, out, err = _run(["fit", *files, "-o", str(tmp_path / "x.json")])
    assert code == 0, err
    share = float(out.split("29 plateaus carry ")[1].split(" %")[0])
    assert share >= 20  # 3 % when a ramp's samples shared the plateaus' command cells
    datasets = load_datasets(files)
    (row,) = compare(datasets, ["motor"], "by-file")
    data = pool(datasets, Selection())
    before = []  # the same folds with the command cells pooled over every file
    for i in range(len(files)):
        train, test = data.file_index != i, data.file_index == i
        coef = fit_coefficients(MODELS["motor"], *data.take(train), "l2")
        tt, bt, tht = data.take(test)
        before.append(np.abs(MODELS["motor"].evaluate(coef, tt, bt) - tht))
    pooled = float(np.mean(np.concatenate(before)))
    assert row.all.n == 203
    assert row.all.mean_pct <= 0.66 < pooled
    (pair,) = compare(datasets[1:], ["motor"], "by-file")
    assert pair.all.mean_pct <= 0.6


def test_44_a_long_l1_fit_stops_within_a_second_of_ctrl_c(tmp_path: Path) -> None:
    """Item 13: `fit --all-samples --loss l1 --model poly4` on a long log solves an LP for
    many seconds; Ctrl-C stops it within a second (exit 130, no map written), where HiGHS in
    the main thread once held the signal until the LP ended (~31 s)."""
    import os
    import signal
    import subprocess
    import time

    rng = np.random.default_rng(44)
    n = 20000
    t_s = np.arange(n) * 0.01
    pct = 10 + 60 * (t_s / t_s[-1])
    volt = 24.0 - 2.0 * t_s / t_s[-1]
    thrust = 12.0 * (pct / 100) ** 2 * volt / 24 + rng.standard_t(2, n) * 0.02
    rows = ["Time (s),ESC signal (µs),Thrust (N),Voltage (V)"]
    rows += [f"{a:.2f},{1000 + 10 * p:.1f},{f:.4f},{v:.3f}"
             for a, p, f, v in zip(t_s, pct, thrust, volt, strict=True)]  # fmt: skip
    log = tmp_path / "long.csv"
    log.write_text("\n".join(rows) + "\n", encoding="utf-8")
    out = tmp_path / "l1.json"
    root = Path(__file__).resolve().parent.parent
    env = {**os.environ, "PYTHONPATH": str(root)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "thrustmap", "fit", str(log), "--all-samples", "--loss", "l1",
         "--model", "poly4", "-o", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )  # fmt: skip
    time.sleep(4.0)  # imported, loaded, inside the LP
    assert proc.poll() is None, proc.communicate()
    sent = time.monotonic()
    proc.send_signal(signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=20)
    finally:
        proc.kill()
    took = time.monotonic() - sent
    assert proc.returncode == 130, err
    assert took < 1.0, f"{took:.2f} s after Ctrl-C"
    assert "interrupted" in err and not out.exists()


def test_44_long_solving_says_so(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """Item 13: solving that runs past PROGRESS_EVERY_S says what it is doing, on stderr."""
    import time

    from thrustmap.fitting import solve

    monkeypatch.setattr(solve, "PROGRESS_EVERY_S", 0.2)
    monkeypatch.setattr(solve, "PROGRESS_MIN_POINTS", 1)
    monkeypatch.setattr(solve, "_heartbeat", solve._Heartbeat())
    real = solve.interruptible

    def slow(work: object, what: str) -> object:
        return real(lambda: (time.sleep(0.5), work())[1], what)  # type: ignore[operator]

    monkeypatch.setattr(solve, "interruptible", slow)
    code, _, err = _run(["fit", str(FIXTURES / "sweeps" / "msp_run.csv"), "--loss", "l1",
                         "-o", str(tmp_path / "m.json")])  # fmt: skip
    assert code == 0, err
    assert "solving the exact L1 fit" in err and "Ctrl-C stops it" in err


def test_44_a_fleet_names_a_log_copied_under_two_names(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Item 2 in the fleet: a log copied under two names is one Df (named by content), pooled
    once, and the identity check's words name both copies."""
    from thrustmap.fleet.groups import group_logs
    from thrustmap.fleet.task import Outcome

    def row(path: str) -> Outcome:
        return Outcome(path, sha256="ab" * 32, status="ok", df_path="df/x.csv", samples=100,
                       airframe='{"rotors": 4}', airframe_key="k", voltage_min_v=21.0,
                       voltage_max_v=24.0)  # fmt: skip

    (group,) = group_logs([row("a/flight.ulg"), row("b/flight-copy.ulg")], tmp_path)
    assert len(group.df_paths) == 1 and group.samples == 100
    assert "a/flight.ulg and b/flight-copy.ulg are the same content" in caplog.text
    assert "counted once" in caplog.text


# --- wave 5 (branch unseen): careless inputs nobody had tried ------------------------------


@pytest.fixture(scope="module")
def work_unseen(work: dict[str, str]) -> dict[str, str]:
    tmp = Path(work["tmp"]) / "unseen"
    tmp.mkdir()
    for name in ("msp_run.csv", "msp_run.meta.json"):  # a recording, as `sweep` leaves it
        shutil.copy(FIXTURES / "sweeps" / name, tmp / name)
    shutil.copy(FL / "sim_hover.ulg", tmp / "flight.ulg")
    _step_summary(tmp / "other_tool.csv", 11.1)  # another tool's stand log (no sidecar)
    assert _run(["export", work["map"], "--to", "px4", "-o", str(tmp / "px4.params")])[0] == 0
    doc = json.loads((FL / "sim_map.json").read_text())  # the same motor measured on 1S
    doc["validity"]["voltage_v"] = [3.4, 4.2]
    doc["coefficients"] = [c / 6.0 if i else c for i, c in enumerate(doc["coefficients"])]
    (tmp / "one_cell_map.json").write_text(json.dumps(doc))
    lines = (FIXTURES / "sweeps" / "msp_run.csv").read_text().splitlines()
    body = lines[1:]
    np.random.default_rng(5).shuffle(body)  # sorted by another column in a spreadsheet
    (tmp / "shuffled.csv").write_text("\n".join([lines[0], *body]) + "\n")
    held = [",".join([r.split(",")[0], "1500", *r.split(",")[2:]]) for r in lines[1:]]
    (tmp / "one_level.csv").write_text("\n".join([lines[0], *held]) + "\n")  # not the command
    return {**work, "u": str(tmp), "fl": str(FL)}


ROWS_UNSEEN = [
    Row(
        "an export written over a recorded stand log",
        "export {map} --to px4 -o {u}/msp_run.csv",
        2,
        "recorded data is never overwritten",
    ),
    Row(
        "a Df written over a recorded stand log",
        "flightlog extract {ulg} --mass-kg 1.5 -o {u}/msp_run.csv",
        2,
        "would overwrite a recorded stand log",
    ),
    Row(
        "a map written over a flight log",
        "fit {run} -o {u}/flight.ulg",
        2,
        "would overwrite a flight log",
    ),
    Row(
        "a report written over another tool's stand log",
        "report {map} {run} -o {u}/other_tool.csv",
        2,
        "a CSV that is not a Df thrustmap wrote",
    ),
    Row(
        "export --range in percent for PWM µs",
        "export {map} --to pwm --range 0:100",
        2,
        "outside what pwm can be on the wire",
    ),
    Row(
        "export --range in milliseconds for PWM µs",
        "export {map} --to pwm --range 1.1:1.94",
        2,
        "is it in another unit?",
    ),
    Row(
        "export --range as a fraction for percent",
        "export {map} --to percent --range 0:1",
        2,
        "under a quarter of percent's 0:100",
    ),
    Row(
        "export --range in percent for DShot",
        "export {map} --to dshot --range 0:100",
        2,
        "under a quarter of dshot's 48:2047",
    ),
    Row(
        "export --range PWM µs for OneShot125",
        "export {map} --to oneshot125 --range 1000:2000",
        2,
        "outside what oneshot125 can be on the wire",
    ),
    Row(
        "a sweep of 0.001 % steps (50,001 levels, 42 h)",
        "sweep stairs-up --stand sim://tyto-1585 --step 0.001 --dry-run -o {u}/s1.csv",
        2,
        "a sweep is at most 5,000 segments and 4 h",
    ),
    Row(
        "a sweep repeated a million times (never built)",
        "sweep steps --stand sim://tyto-1585 --repeats 1000000 --dry-run -o {u}/s2.csv",
        2,
        "20,000,001 segments",
    ),
    Row(
        "a dwell of 1e9 s",
        "sweep stairs-up --stand sim://tyto-1585 --dwell 1e9 --dry-run -o {u}/s3.csv",
        2,
        "check --step, --dwell",
    ),
    Row(
        "a ramp of 1e12 s",
        "sweep ramp --stand sim://tyto-1585 --duration 1e12 --dry-run -o {u}/s4.csv",
        2,
        "plan 'ramp' would be 4 segments",
    ),
    Row(
        "explicit levels typed as fractions",
        "sweep explicit --stand sim://tyto-1585 --levels 0.1,0.2,0.3 --dry-run -o {u}/s5.csv",
        2,
        "fractions? 0.3 is 30 %",
    ),
    Row(
        "a thrust limit in grams",
        "sweep stairs-up --stand sim://tyto-1585 --max-thrust 20000 --dry-run -o {u}/s6.csv",
        2,
        "grams typed as newtons?",
    ),
    Row(
        "a current limit in milliamps",
        "spin sim://betaflight --motor 1 --throttle 10 --max-current 60000 --yes",
        2,
        "milliamps typed as amperes?",
        absent="spinning",
    ),
    Row(
        "a temperature limit in °F, or none",
        "sweep stairs-up --stand sim://tyto-1585 --max-temp 2000 --dry-run -o {u}/s7.csv",
        2,
        "at most 200 °C",
    ),
    Row(
        "a stand watchdog in milliseconds",
        "sweep stairs-up --stand sim://tyto-1585 --stale-s 500 --dry-run -o {u}/s8.csv",
        2,
        "--stale-s 500 s: at most 60 s",
    ),
    Row(
        "a stand log whose rows are out of time order",
        "fit {u}/shuffled.csv -o {u}/m.json",
        2,
        "time goes backwards",
        absent="never leaves the load cell's noise",
    ),
    Row(
        "evaluate with the log and the map swapped",
        "evaluate {run} {map}",
        2,
        "a CSV, e.g. a stand log or a Df, not a JSON file",
    ),
    Row(
        "compare with an empty --models",
        "compare {run} --models ~",
        2,
        "names no model",
    ),
    Row(
        "gamma fit on an export's text",
        "gamma fit {u}/px4.params --map {map} -o {u}/g.json",
        2,
        "do not form one table",
        absent="tokeniz",
    ),
    Row(
        "a record longer than the settling hold",
        "sweep stairs-up --stand sim://tyto-1585 --settle --record 100 --dwell 2 --dry-run "
        "-o {u}/s9.csv",
        2,
        "it could never be recorded",
    ),
    Row(
        "gamma fit with a rotor count the Df's log contradicts",
        "gamma fit {tmp}/df.csv --map {map} --rotors 6 -o {u}/g6.json",
        2,
        "--rotors 6, but the Df's logs record 4 rotors",
    ),
    Row(
        "a flight on another pack than the map's (a 1S map for a 6S flight)",
        "flightlog extract {ulg} --mass-kg 0.03 --map {u}/one_cell_map.json -o {u}/d1s.csv",
        2,
        "the flight's battery reads 6S",
    ),
    Row(
        "gamma fit of a 6S flight against a 1S map",
        "gamma fit {tmp}/df.csv --map {u}/one_cell_map.json -o {u}/g1s.json",
        2,
        "but the map was measured on a 1S pack",
    ),
    Row(
        "gamma live with the mass in grams writes no map",
        "gamma live replay://{fl}/live_hover.tlog --map {map} --mass-kg 1500 -o {u}/gl.json",
        0,
        "γ not determined (γ(B) reaches",
        absent="), map ",
    ),
    Row(
        "compare with a voltage range in millivolts (was an internal error)",
        "compare {run} --voltage-range 20000:26000",
        2,
        "no point is left after selection",
    ),
    Row(
        "evaluate with a range that keeps nothing (was a table of n=0, exit 0)",
        "evaluate {map} {run} --voltage-range 20000:26000",
        2,
        "--voltage-range in V, not mV",
    ),
    Row(
        "fit with a throttle range in percent on a µs log",
        "fit {run} --throttle-range 10:60 -o {u}/m.json",
        2,
        "not %",
    ),
    Row(
        "a stand log whose throttle column holds one value (fitted 0.000 %, exit 0)",
        "fit {u}/one_level.csv -o {u}/m1l.json",
        2,
        "every point is at one throttle (50.0 %)",
    ),
    Row(
        "a spin whose ramp outlasts it",
        "spin sim://betaflight --motor 1 --throttle 10 --ramp 60 --seconds 2 --yes",
        2,
        "would reach only 0.333 % of the 10 % asked",
        absent="spinning",
    ),
    Row(
        "a negative spin limit is refused before anything opens",
        "spin sim://betaflight --motor 1 --throttle 10 --max-current -5 --yes",
        2,
        "--max-current -5: expected a number > 0",
        absent="spinning",
    ),
]


@pytest.mark.parametrize("row", ROWS_UNSEEN, ids=[r.name for r in ROWS_UNSEEN])
def test_careless_input_unseen(row: Row, work_unseen: dict[str, str]) -> None:
    test_careless_input(row, work_unseen)
    if row.argv.startswith("gamma live"):  # a γ outside the band is never written as a map
        assert not Path(work_unseen["u"], "gl.json").exists()
    if row.code == 2 and "{u}/" in row.argv:  # the file refused as an output is unchanged
        target = Path(_argv(row, work_unseen)[-1])
        if target.name in ("msp_run.csv", "flight.ulg"):
            source = (
                FIXTURES / "sweeps" / "msp_run.csv"
                if target.suffix == ".csv"
                else FL / "sim_hover.ulg"
            )
            assert target.read_bytes() == source.read_bytes()


# -- predict: a voltage of another pack, a throttle below spin-up, a voltage distance ----------
# (the coordinator's rows for what the wave's careless-input search routed to predict)
PREDICT_ROWS = [
    ("--thrust-n 4 --voltage-v 16.8", 0, "a 4S pack? The answer is this motor on that pack", None),
    ("--throttle-pct 0.5 --voltage-v 24", 0, "did you mean 50 %?", None),
    ("--thrust-n 4 --voltage-v 21", 0, "the voltage distance included", "widened ×1.00"),
]


@pytest.mark.parametrize(("args", "code", "phrase", "absent"), PREDICT_ROWS)
def test_predict_careless_input_on_the_demo_map(
    demo_run: DemoRun, args: str, code: int, phrase: str, absent: str | None
) -> None:
    """On the demo's 6S single-rotor map: 16.8 V (a full 4S pack: the motor on another pack, a
    legitimate cross-voltage question) was answered as an extrapolation "widened ×1.00" with no
    word of the pack; 0.5 % throttle (below the measured spin-up) gave a thrust
    with no word; a voltage a little below the data said "widened ×1.00, from ±x to ±x"."""
    sr_map = demo_run.folder / "thrustmap-demo" / "sr-map.json"
    got, out, err = _run(["predict", str(sr_map), *args.split()], None)
    assert got == code, out + err
    assert phrase in out + err, out + err
    assert "Traceback" not in err
    if absent is not None:
        assert absent not in out + err


# -- routed: the defects a colleague found on fc15565 -----------------------------------------


@pytest.fixture(scope="module")
def work_routed(work_unseen: dict[str, str]) -> dict[str, str]:
    tmp = Path(work_unseen["u"]) / "routed"
    tmp.mkdir()
    (tmp / "logs").mkdir()
    shutil.copy(FL / "sim_hover.ulg", tmp / "logs" / "flight.ulg")
    (tmp / "src").mkdir()  # a map fitted on a stand log that was then overwritten
    for name in ("msp_run.csv", "msp_run.meta.json"):
        shutil.copy(FIXTURES / "sweeps" / name, tmp / "src" / name)
    assert _run(["fit", str(tmp / "src" / "msp_run.csv"), "-o", str(tmp / "src_map.json")])[0] == 0
    (tmp / "src" / "msp_run.csv").write_text("time,signal\n0,1\n", encoding="utf-8")
    return {**work_unseen, "r": str(tmp)}


ROWS_ROUTED = [
    Row(
        "fleet extract of 6S flights with a 1S map (extracted, exit 0)",
        "fleet extract {r}/logs --map {u}/one_cell_map.json --mass-kg 1.5 --workers 0 --quiet "
        "-o {r}/f1s",
        0,
        "refused: {r}/logs/flight.ulg: --map: the flight's battery reads 6S",
        absent="1 extracted",
    ),
    Row(
        "fleet extract with the mass in grams against a map (extracted, exit 0)",
        "fleet extract {r}/logs --map {map} --mass-kg 1500 --workers 0 --quiet -o {r}/fheavy",
        0,
        "refused: {r}/logs/flight.ulg: --map: mass 1500 kg on 4 rotors needs 3677 N",
        absent="1 extracted",
    ),
    Row(
        "a Df resampled at 1 GHz (blamed the log's timestamps)",
        "flightlog extract {ulg} --mass-kg 1.5 --rate-hz 1e9 -o {r}/d1g.csv",
        2,
        "--rate-hz 1e+09: expected 0.5..1000 Hz",
        absent="timestamp",
    ),
    Row(
        "a Df resampled at 0.001 Hz (wrote an empty Df, exit 0)",
        "flightlog extract {ulg} --mass-kg 1.5 --rate-hz 0.001 -o {r}/d1m.csv",
        2,
        "--rate-hz 0.001: expected 0.5..1000 Hz",
    ),
    Row(
        "a rotor count no vehicle has",
        "flightlog extract {ulg} --mass-kg 1.5 --rotors 4000 -o {r}/d4k.csv",
        2,
        "--rotors 4000: expected 1..64 rotors",
    ),
    Row(
        "a tilt filter no hovering multirotor passes (wrote an empty Df, exit 0)",
        "flightlog extract {ulg} --mass-kg 1.5 --tilt-max-deg 0.5 -o {r}/dtilt.csv",
        2,
        "--tilt-max-deg 0.5: expected 1..90 deg",
    ),
    Row(
        "a mass a thousand times too light for the map (extracted, exit 0)",
        "flightlog extract {ulg} --mass-kg 0.001 --map {map} -o {r}/dlight.csv",
        2,
        "thrust-to-weight above 30 is no multirotor's",
    ),
    Row(
        "fleet extract on 100,000 workers (said 'memory limit 0.00 GiB per worker')",
        "fleet extract {r}/logs --mass-kg 1.5 --workers 100000 --quiet -o {r}/fw",
        2,
        "--workers 100000: at most",
        absent="GiB per worker",
    ),
    Row(
        "report on a map whose source changed since the fit (blamed the header)",
        "report {r}/src_map.json -o {r}/changed.html",
        2,
        "msp_run.csv' changed since the fit: its content differs from what the map was fitted on",
        absent="header",
    ),
    Row(
        "plot sweep on a map whose source changed since the fit (blamed the header)",
        "plot sweep {r}/src_map.json -o {r}/changed.png",
        2,
        "msp_run.csv' changed since the fit",
        absent="header",
    ),
]


@pytest.mark.parametrize("row", ROWS_ROUTED, ids=[r.name for r in ROWS_ROUTED])
def test_careless_input_routed(row: Row, work_routed: dict[str, str]) -> None:
    test_careless_input(dataclasses.replace(row, phrase=row.phrase.format(**work_routed)),
                        work_routed)  # fmt: skip


def test_fleet_force_records_the_other_pack(work_routed: dict[str, str]) -> None:
    """fleet extract --force extracts a flight on another pack, as flightlog extract --force
    does, and records why in the log's Df sidecar."""
    out = Path(work_routed["r"]) / "f1s_forced"
    code, _, _ = _run(
        ["fleet", "extract", f"{work_routed['r']}/logs", "--map",
         f"{work_routed['u']}/one_cell_map.json", "--mass-kg", "1.5", "--workers", "0",
         "--quiet", "--force", "-o", str(out)]
    )  # fmt: skip
    assert code == 0
    sides = [p for p in (out / "df").glob("*.json") if not p.name.endswith(".outcome.json")]
    assert len(sides) == 1
    forced = json.loads(sides[0].read_text())["forced"]
    assert any("the flight's battery reads 6S" in f for f in forced), forced
