"""`thrustmap sweep` and `thrustmap demo` through the CLI, on the simulator."""

from __future__ import annotations

import logging
import os
import signal
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from thrustmap.cli import main
from thrustmap.fitting.loaders.load import load_dataset
from thrustmap.protocols.msp.framing import MspCommand, MspDecoder
from thrustmap.protocols.msp.motor import SetMotor
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
    # no motor was commanded before the signal: the FC was sent nothing that could spin one
    # (a session that commanded no motor sends no stop either, issue 20)
    assert all(p == STOP for p in set_motor_payloads(tmp_path))
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


# --------------------------------------------------------------------------- exit codes


def test_sweep_help_lists_the_exit_codes_and_every_interlock(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from thrustmap.rig.interlocks import INTERLOCKS

    main(["sweep", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "Exit codes: 0 done" in text and "130 interrupted" in text and "3 stop NOT" in text
    for row in INTERLOCKS:
        assert row.option in text
        if row.default is not None:
            assert f"{row.option} {'INTEGER' if row.value_type is int else 'FLOAT'}" in text
            assert f"[default: {row.default}]" in text


def test_changing_a_default_in_the_table_moves_the_cli_and_the_runner(tmp_path: Path) -> None:
    """The interlock table is the one declaration: edit one default there (here in a copy of the
    module loaded in a fresh interpreter) and both `sweep --help` and the runner's check follow."""
    import subprocess
    import sys

    import thrustmap.rig.interlocks as interlocks

    source = Path(interlocks.__file__).read_text(encoding="utf-8")
    old = '"max_thrust_n", "--max-thrust", "N", 20.0,'
    assert old in source
    edited = tmp_path / "interlocks.py"
    edited.write_text(source.replace(old, old.replace("20.0", "12.5")), encoding="utf-8")
    program = f"""
import sys, types
import thrustmap.rig
module = types.ModuleType("thrustmap.rig.interlocks")
module.__file__ = {str(edited)!r}
sys.modules[module.__name__] = module
exec(compile(open(module.__file__).read(), module.__file__, "exec"), module.__dict__)
from thrustmap.rig.interlocks import Limits, Reading, check
from thrustmap.rig.runner import Runner  # the runner uses this table
print("runner", Limits().max_thrust_n, check(Limits(), Reading(thrust_n=13.0)).limit)
from thrustmap.cli import main
main(["sweep", "--help"])
"""
    done = subprocess.run(
        [sys.executable, "-c", program], capture_output=True, text=True, timeout=60
    )
    out = " ".join(done.stdout.split())
    assert "runner 12.5 thrust" in out, done.stderr
    assert "--max-thrust FLOAT Stop above this thrust. [N] [default: 12.5]" in out


def sweep_main(tmp_path: Path, *extra: str) -> int:
    with pytest.raises(SystemExit) as exc:
        main([*sweep_args(tmp_path), *extra])
    return int(exc.value.code or 0)


def test_sweep_exit_codes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from thrustmap.rig.fc.msp import MspThrottleOutput
    from thrustmap.rig.sim import peers

    peers.reset_benches()
    # a tripped limit: aborted, the stop verified -> 1
    assert sweep_main(tmp_path, "--max-thrust", "0.3") == 1
    out = capsys.readouterr().out
    assert "aborted" in out and "limit tripped: thrust" in out and "stop verified" in out
    # the stop cannot be verified -> 3 (it is verified once before the run, then never)
    # (every MSP_MOTOR read is judged by _judge: the check before the run and each stop's)
    calls: list[int] = []
    judge = MspThrottleOutput._judge

    def judged(self: MspThrottleOutput, values: tuple[int, ...]) -> str:
        calls.append(1)
        return judge(self, values) if len(calls) == 1 else "running"

    monkeypatch.setattr(MspThrottleOutput, "_judge", judged)
    peers.reset_benches()  # a fresh simulated bench for a fresh simulated clock
    assert sweep_main(tmp_path, "-o", str(tmp_path / "b.csv")) == 3
    assert "STOP NOT VERIFIED" in capsys.readouterr().out


@pytest.mark.parametrize("fc", ["betaflight", "px4", "ardupilot"])
def test_ctrl_c_while_the_stand_is_tared_exits_130_without_a_critical(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
    fc: str,
) -> None:
    """Issue 11 item 7: Ctrl-C while the stand is tared (the FC link serviced meanwhile) stops
    at once: exit 130, the stop verified, no CRITICAL, nothing but stops ever sent."""
    from thrustmap.rig.sim import peers
    from thrustmap.rig.stand.tyto import TytoStand

    peers.reset_benches()
    serviced: list[int] = []
    tare = TytoStand.tare

    def interrupted_tare(
        self: TytoStand, service: Callable[[], None] | None = None, polls: int = 20
    ) -> None:
        def ctrl_c() -> None:
            if service is not None:
                service()  # the runner reads the FC between the stand's polls ...
            serviced.append(1)
            if len(serviced) == 10:
                raise KeyboardInterrupt  # ... and the operator presses Ctrl-C half-way

        tare(self, ctrl_c, polls)

    monkeypatch.setattr(TytoStand, "tare", interrupted_tare)
    url = f"record://sim://{fc}?bench=cli&file={tmp_path / 'fc.jsonl'}"
    argv = sweep_args(tmp_path)
    argv[argv.index("--throttle") + 1] = url
    with caplog.at_level(logging.WARNING), pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 130
    captured = capsys.readouterr()
    assert len(serviced) == 10
    assert captured.out.startswith("aborted: ") and "interrupted (Ctrl-C)" in captured.out
    assert "stop verified" in captured.out and "NOT VERIFIED" not in captured.out
    assert not [r for r in caplog.records if r.levelno >= logging.CRITICAL]
    assert "CRITICAL" not in captured.err
    if fc == "betaflight":
        payloads = set_motor_payloads(tmp_path)
        assert all(p == STOP for p in payloads)  # nothing but stops (if any) was sent


@pytest.mark.parametrize(
    ("url", "message"),
    [
        ("tcp:127.0.0.1:9", "cannot open tcp:127.0.0.1:9"),
        ("socket://127.0.0.1:9", "cannot open socket://127.0.0.1:9"),
        ("/dev/ttyTHRUSTMAP-NONE", "cannot open /dev/ttyTHRUSTMAP-NONE"),
        ("nosuch://x", "cannot open nosuch://x"),
        ("sim://nosuch", "unknown simulated peer 'nosuch'"),
    ],
)
@pytest.mark.parametrize("command", ["sweep", "spin"])
def test_every_url_form_fails_in_one_line_with_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], url: str, message: str, command: str
) -> None:
    if command == "sweep":  # the stand's URL (a real stand on a bad URL fails at once)
        argv = ["sweep", "steps", "--stand", url, "--yes", "-q", "-o", str(tmp_path / "x.csv")]
        if url.startswith("tcp:"):
            message = "tcp:127.0.0.1:9 is a flight controller (mavlink), not a thrust stand"
    else:
        argv = ["spin", url, "--motor", "1", "--throttle", "5", "--yes"]
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("error: ") and message in err[-1]
    assert "internal error" not in "\n".join(err) and "Traceback" not in "\n".join(err)


def test_a_simulated_stand_with_a_real_fc_is_warned_before_anything(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    main(["sweep", "steps", "--stand", STAND, "--throttle", "tcp:127.0.0.1:9", "--dry-run",
          "-o", str(tmp_path / "x.csv")])  # fmt: skip
    err = capsys.readouterr().err
    assert "warning: the stand sim://" in err and "thrust will be noise" in err
