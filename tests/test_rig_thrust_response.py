"""Thrust must follow the command: the interlock, the simulated bench pairing that makes it
testable, and `fit` refusing a log of pure noise."""

from __future__ import annotations

import json
import random
from pathlib import Path

import pytest

from thrustmap.cli import main
from thrustmap.fitting.loaders.load import load_dataset
from thrustmap.rig.interlocks import RESPONSE_S, Limits, ThrustResponse
from thrustmap.rig.sim.pairing import pair_sim_urls

SWEEP = ["sweep", "steps", "--stand", "sim://tyto-1585", "--throttle", "sim://betaflight"]


def sweep(tmp_path: Path, *extra: str) -> tuple[int, Path]:
    """Run the issue's sweep (steps to 40 %); (exit code, Ds log)."""
    out = tmp_path / "run.csv"
    try:
        main([*SWEEP, "--to", "40", "-o", str(out), "--yes", "--quiet", *extra])
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    return code, out


def test_two_sim_urls_form_one_bench(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The issue's command: the simulated stand measures the motor the simulated FC drives."""
    code, out = sweep(tmp_path)
    printed = capsys.readouterr()
    assert code == 0, printed.err
    assert "completed" in printed.out and "stop verified" in printed.out
    ds = load_dataset(out)
    at_40 = ds.thrust_n[ds.throttle_pct > 39.5]
    assert at_40.size and float(at_40.mean()) > 2.0  # a 2207 motor at 40 %: ~3 N, not noise


def test_thrown_propeller_aborts_within_two_steps_and_fit_refuses_the_log(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--sim-apart: the stand measures a rotor nobody drives (a thrown propeller)."""
    code, out = sweep(tmp_path, "--sim-apart")
    printed = capsys.readouterr()
    assert code == 1, printed.out + printed.err
    assert "thrust did not rise above the stand's noise" in printed.out
    assert "at 15.0 % confirmed by the throttle output" in printed.out
    assert "stop verified" in printed.out
    meta = json.loads(out.with_suffix(".meta.json").read_text())
    assert meta["stop_verified"] is True and meta["outcome"]["status"] == "aborted"
    ds = load_dataset(out)
    assert ds.step is not None and int(ds.step.max()) <= 1  # the low step and the first step
    # fit refuses it: exit 2, one line naming the file
    with pytest.raises(SystemExit) as info:
        main(["fit", str(out), "-o", str(tmp_path / "map.json")])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f"error: {out}: thrust never leaves the load cell's noise")
    assert not (tmp_path / "map.json").exists()


def test_fit_refuses_a_completed_log_of_noise(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """What the old code wrote: the interlock off, the run 'completes' with thrust in noise."""
    code, out = sweep(tmp_path, "--sim-apart", "--min-thrust-by", "0")
    assert code == 0
    with pytest.raises(SystemExit) as info:
        main(["fit", str(out), "-o", str(tmp_path / "map.json")])
    assert info.value.code == 2
    assert "with the throttle up to 40 %" in capsys.readouterr().err


def _rest(check: ThrustResponse, sigma: float = 0.02) -> None:
    rng = random.Random(3)
    for i in range(100):
        check.rest_sample(i * 0.01, rng.gauss(0.0, sigma))
    check.start(tared=True)


def test_response_collapse_mid_run_trips_after_the_response_time() -> None:
    check = ThrustResponse(Limits(), plan_ceiling_pct=60.0)
    _rest(check)
    assert check.band_n is not None and 0.09 < check.band_n < 0.2
    t = 0.0
    for _ in range(200):  # 40 % with real thrust
        t += 0.02
        assert check.update(t, 40.0, 3.0, 20000.0) is None
    trip = None
    collapse_at = t
    while trip is None and t < collapse_at + 5:
        t += 0.02
        trip = check.update(t, 40.0, 0.01, 31000.0)  # the propeller is gone: rpm up, thrust 0
    assert trip is not None and trip.limit == "thrust response"
    assert RESPONSE_S <= t - collapse_at <= RESPONSE_S + 0.05
    assert "collapsed" in trip.message and "the motor turns (31000 rpm)" in trip.message


def test_response_ignores_low_commands_and_scales_with_the_plan() -> None:
    check = ThrustResponse(Limits(), plan_ceiling_pct=60.0)
    _rest(check)
    # below the threshold (15 %) no thrust is fine (an ESC below its start, the low step)
    assert all(check.update(i * 0.02, 10.0, 0.0, None) is None for i in range(500))
    small = ThrustResponse(Limits(), plan_ceiling_pct=8.0)  # a plan that never reaches 15 %
    assert small.threshold_pct == 8.0
    off = ThrustResponse(Limits(min_thrust_by_pct=0), plan_ceiling_pct=60.0)
    _rest(off)
    assert not off.enabled and off.update(10.0, 60.0, 0.0, None) is None
    unknown = ThrustResponse(Limits(), plan_ceiling_pct=60.0)  # no at-rest readings: off
    unknown.start(tared=True)
    assert unknown.update(10.0, 60.0, 0.0, None) is None


def test_pairing_of_sim_urls() -> None:
    assert pair_sim_urls("sim://tyto-1585", "sim://betaflight") == "sim://tyto-1585?drive_esc=0"
    assert (
        pair_sim_urls("sim://tyto-1585?seed=3", "sim://px4?bench=b2")
        == "sim://tyto-1585?seed=3&bench=b2&drive_esc=0"
    )
    assert pair_sim_urls("sim://tyto-1585?drive_esc=1", "sim://betaflight").endswith("drive_esc=1")
    assert (
        pair_sim_urls("sim://tyto-1585", "sim://betaflight", apart=True)
        == "sim://tyto-1585?bench=default-apart&drive_esc=0"
    )
    recorded = pair_sim_urls("record://sim://tyto-1585?file=s.jsonl", "sim://betaflight")
    assert recorded == "record://sim://tyto-1585?file=s.jsonl&drive_esc=0"
    # a real device on either side: untouched
    assert pair_sim_urls("/dev/ttyUSB0", "sim://betaflight") == "/dev/ttyUSB0"
    assert pair_sim_urls("sim://tyto-1585", "/dev/ttyACM0") == "sim://tyto-1585"
    assert pair_sim_urls("sim://line-stand", "sim://betaflight") == "sim://line-stand"


def test_a_simulated_stand_beside_a_real_motor_turns_the_interlock_off(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """Its thrust is noise by design (the real Betaflight SITL suite runs such sweeps)."""
    args = ["sweep", "steps", "--stand", "sim://tyto-1585?drive_esc=0", "--to", "40"]
    main([*args, "--throttle", "/dev/ttyACM0", "-o", str(tmp_path / "r.csv"), "--dry-run"])
    err = capsys.readouterr().err
    assert "the thrust-response interlock (--min-thrust-by) is off" in err
    main([*args, "--throttle", "sim://betaflight", "-o", str(tmp_path / "r.csv"), "--dry-run"])
    assert "--min-thrust-by" not in capsys.readouterr().err


def test_answering_n_refuses_the_sweep_with_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import io

    monkeypatch.setattr("sys.stdin", io.StringIO("n\n"))
    with pytest.raises(SystemExit) as info:
        main([*SWEEP, "--to", "40", "-o", str(tmp_path / "run.csv")])
    assert info.value.code == 2  # refused, nothing spun (not 130: nothing was interrupted)
    assert "refused: nothing spun" in capsys.readouterr().err
    assert not (tmp_path / "run.csv").exists()
