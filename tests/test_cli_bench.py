"""`thrustmap sweep` and `thrustmap demo` through the CLI, on the simulator."""

from __future__ import annotations

import os
import signal
from pathlib import Path
from typing import Any

import pytest

from thrustmap.cli import main
from thrustmap.fitting.loaders import load_dataset
from thrustmap.protocols.msp.framing import MspDecoder
from thrustmap.protocols.msp.messages import MspCommand, SetMotor
from thrustmap.protocols.transcript import read_transcript

STAND = "sim://tyto-1585?bench=cli&drive_esc=0"
STOP = SetMotor.stop_all(8).encode()


def fc_url(tmp_path: Path) -> str:
    return f"record://sim://betaflight?bench=cli&protocol=PWM&file={tmp_path / 'fc.jsonl'}"


def set_motor_payloads(tmp_path: Path) -> list[bytes]:
    frames = MspDecoder().feed(read_transcript(tmp_path / "fc.jsonl").written())
    return [f.payload for f in frames if f.cmd == MspCommand.SET_MOTOR]


def sweep_args(tmp_path: Path) -> list[str]:
    return [
        "sweep",
        "stairs-up",
        "--stand",
        STAND,
        "--throttle",
        fc_url(tmp_path),
        "--to",
        "30",
        "--step",
        "10",
        "--dwell",
        "1",
        "-o",
        str(tmp_path / "run.csv"),
        "--yes",
        "--quiet",
    ]


def test_sweep_records_a_loadable_log(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    main(sweep_args(tmp_path))
    out = capsys.readouterr().out
    assert "completed" in out and "stop verified" in out
    ds = load_dataset(tmp_path / "run.csv")
    assert ds.meta["outcome"]["status"] == "completed"
    assert {10, 20, 30} <= {round(float(p)) for p in ds.throttle_pct}
    payloads = set_motor_payloads(tmp_path)
    assert payloads[-1] == STOP and any(p != STOP for p in payloads)


def test_sigterm_before_the_run_still_stops(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import thrustmap.rig.session as session

    def killed(*args: Any, **kwargs: Any) -> None:
        os.kill(os.getpid(), signal.SIGTERM)  # arrives after the devices are open
        raise AssertionError("SIGTERM did not unwind")

    monkeypatch.setattr(session, "record_sweep", killed)
    with pytest.raises(SystemExit) as exc:
        main(sweep_args(tmp_path))
    assert exc.value.code == 130
    assert set_motor_payloads(tmp_path)[-1] == STOP  # the FC's exit sent (and verified) the stop
    assert "stopped (verified)" not in capsys.readouterr().out  # no run result was claimed


def test_dry_run_and_ceiling(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    main(["sweep", "steps", "--stand", STAND, "-o", str(tmp_path / "x.csv"), "--dry-run"])
    out = capsys.readouterr().out
    assert "plan 'steps'" in out and "limits ok" in out
    assert not (tmp_path / "x.csv").exists()
    with pytest.raises(SystemExit) as exc:
        main(
            [
                "sweep",
                "steps",
                "--stand",
                STAND,
                "--to",
                "90",
                "-o",
                str(tmp_path / "x.csv"),
                "--yes",
            ]
        )
    assert exc.value.code == 2
    assert "above the 80.0 % ceiling" in capsys.readouterr().err
