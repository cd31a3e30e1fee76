"""The Ds log module: typed rows, never overwriting, outcome kept through disk errors, and a
loader that uses what the runner recorded (steps, settled marks) instead of guessing."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import numpy as np
import pytest

from thrustmap.core import stand_recording
from thrustmap.core.errors import ConfigError, DataFormatError
from thrustmap.core.units import SCALES
from thrustmap.fitting.loaders.load import load_dataset
from thrustmap.fitting.selection.options import Selection
from thrustmap.fitting.selection.points import select

PROJECT = Path(__file__).resolve().parent.parent


def test_misspelt_field_is_an_error_not_an_empty_column(tmp_path: Path) -> None:
    w = stand_recording.DsWriter(tmp_path / "run.csv", SCALES["pwm"], {})
    with pytest.raises(ValueError, match="unknown Ds log field.*thrust_N"):
        w.write(0.0, 1100, {"thrust_N": 1.0, "voltage_v": 16.0})
    with pytest.raises(TypeError, match="'rpm' must be a number"):
        w.write(0.0, 1100, {"thrust_n": 1.0, "voltage_v": 16.0, "rpm": "fast"})  # type: ignore[dict-item]
    w.write(0.0, 1100, {"thrust_n": 1.0, "voltage_v": 16.0, "step": 0, "phase": "hold"})
    w.finish("completed")
    lines = (tmp_path / "run.csv").read_text().splitlines()
    assert len(lines) == 2  # header + the one good row: nothing of the bad ones
    assert lines[1] == "0.000000,1100,1,16,,,,,,0,hold"
    assert stand_recording.DATA_COLUMNS[:2] == ("thrust_n", "voltage_v")


def test_writer_never_overwrites_a_recording(tmp_path: Path) -> None:
    (tmp_path / "run.csv").write_text("precious\n")
    with pytest.raises(ConfigError, match="refusing to overwrite"):
        stand_recording.DsWriter(tmp_path / "run.csv", SCALES["pwm"], {})
    assert (tmp_path / "run.csv").read_text() == "precious\n"
    (tmp_path / "b.meta.json").write_text("{}")
    with pytest.raises(ConfigError, match="b.meta.json"):
        stand_recording.DsWriter(tmp_path / "b.csv", SCALES["pwm"], {})


def _full_disk_writer(tmp_path: Path) -> stand_recording.DsWriter:
    w = stand_recording.DsWriter(tmp_path / "run.csv", SCALES["pwm"], {"rotors_on_esc": 1})
    for k in range(3):
        w.write(0.1 * k, 1200, {"thrust_n": 1.0 + k, "voltage_v": 16.0, "step": 0})
    w._file.close()  # type: ignore[union-attr]
    w._file = open("/dev/full", "w", encoding="utf-8")  # noqa: SIM115 - every write: ENOSPC
    return w


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
def test_disk_full_keeps_outcome_and_stop_verification(tmp_path: Path) -> None:
    w = _full_disk_writer(tmp_path)
    with pytest.raises(ConfigError, match="cannot write the Ds log after 3 rows: No space"):
        w.write(0.3, 1200, {"thrust_n": 4.0, "voltage_v": 16.0})
    w.finish("aborted", "ConfigError: disk full", extra={"stop_verified": True})
    meta = json.loads((tmp_path / "run.meta.json").read_text())
    assert meta["outcome"]["status"] == "aborted" and meta["stop_verified"] is True
    assert "No space" in meta["outcome"]["csv_error"] and meta["samples"] == 3
    ds = load_dataset(tmp_path / "run.csv")
    assert len(ds) == 3 and "partial" in ds.meta


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
def test_completed_status_with_a_lost_row_is_not_claimed(tmp_path: Path) -> None:
    w = _full_disk_writer(tmp_path)
    with pytest.raises(ConfigError):
        w.write(0.3, 1200, {"thrust_n": 4.0, "voltage_v": 16.0})
    w.finish("completed")
    side = stand_recording.read_sidecar(tmp_path / "run.csv")
    assert side is not None and side.status == "aborted"
    assert "could not be written" in side.reason


def test_sidecar_outcome_written_in_place_when_no_new_file_fits(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    plan = {"segments": [{"type": "hold", "label": "x" * 40}] * 30}
    w = stand_recording.DsWriter(
        tmp_path / "run.csv", SCALES["dshot"], {"plan": plan, "rotors_on_esc": 4}
    )
    w.write(0.0, 100, {"thrust_n": 0.5, "voltage_v": 16.0})

    def no_room(path: object, text: str) -> None:
        raise ConfigError("cannot write: the disk is full", file=str(path))

    monkeypatch.setattr(stand_recording, "atomic_write_text", no_room)
    w.finish("aborted", "limit tripped: current " + "x" * 2000, extra={"stop_verified": True})
    side = stand_recording.read_sidecar(tmp_path / "run.csv")
    assert side is not None
    assert (side.status, side.stop_verified, side.samples) == ("aborted", True, 1)
    assert side.reason.startswith("limit tripped: current")
    assert side.throttle_scale == SCALES["dshot"] and side.rotors_on_esc == 4


def _settled_log(tmp_path: Path) -> Path:
    """Two holds; the runner marked each settled part; a spin-down follows the stop."""
    w = stand_recording.DsWriter(tmp_path / "run.csv", SCALES["pwm"], {"rotors_on_esc": 1})
    t = 0.0
    for step, (us, level) in enumerate(((1300, 2.0), (1500, 4.0))):
        for k in range(60):
            # a slow creep the offline detector cannot tell from noise, settled at k = 40
            thrust = level * (1.0 - 0.05 * np.exp(-k / 12.0))
            phase = "stair-settled" if k >= 40 else "stair"
            w.write(t, us, {"thrust_n": thrust, "voltage_v": 16.0, "step": step, "phase": phase})
            t += 0.02
    for k in range(30):
        w.write(t, 1000, {"thrust_n": 4.0 * np.exp(-k / 3), "voltage_v": 16.1, "phase": "stop"})
        t += 0.02
    w.finish("completed")
    return tmp_path / "run.csv"


def test_loader_uses_recorded_steps_and_settled_marks(tmp_path: Path) -> None:
    ds = load_dataset(_settled_log(tmp_path))
    assert ds.step is not None and ds.settled is not None
    assert ds.step.tolist()[:60] == [0] * 60 and set(ds.step.tolist()[-30:]) == {-1}
    pts = select(ds, Selection())
    assert pts.report["plateaus_settled_by_recorder"] == 2
    assert len(pts) == 2  # the spin-down after the stop is not a plateau
    want = [float(np.mean(ds.thrust_n[a : a + 20])) for a in (40, 100)]
    assert pts.thrust_n.tolist() == pytest.approx(want, rel=1e-12)


def test_no_private_imports_between_loader_and_format() -> None:
    loaders = sorted((PROJECT / "thrustmap/fitting/loaders").glob("*.py"))
    assert loaders, "the loaders package moved"
    for path in (*loaders, PROJECT / "thrustmap/core/stand_recording.py"):
        rel = str(path.relative_to(PROJECT))
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module:
                private = [a.name for a in node.names if a.name.startswith("_")]
                assert not private, (rel, node.module, private)
    runner = (PROJECT / "thrustmap" / "rig" / "runner.py").read_text()
    assert (
        "from thrustmap.core.stand_recording import DsWriter" in runner and "fitting" not in runner
    )


def test_sidecar_fields_are_typed(tmp_path: Path) -> None:
    p = _settled_log(tmp_path)
    side = p.with_name("run.meta.json")
    meta = json.loads(side.read_text())
    for key, value, expected in (
        ("rotors_on_esc", "four", "field 'rotors_on_esc': expected an integer"),
        ("outcome", {"status": "done"}, "field 'outcome.status': expected one of"),
        ("throttle_scale", {"name": "pwm", "lo": 2000, "hi": 1000, "unit": "us"}, "LO < HI"),
    ):
        side.write_text(json.dumps({**meta, key: value}))
        with pytest.raises(DataFormatError, match=expected) as exc:
            load_dataset(p)
        assert "run.meta.json" in str(exc.value)


class _DiskFillsUp(stand_recording.DsWriter):
    """A Ds writer whose disk fills up after ``rows_left`` rows (every later write: ENOSPC)."""

    rows_left = 40

    def write_row(self, row: stand_recording.DsRow) -> None:
        if self.rows == self.rows_left and self._file is not None and self.write_error is None:
            self._file.close()
            self._file = open("/dev/full", "w", encoding="utf-8")  # noqa: SIM115
        super().write_row(row)


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
def test_sweep_on_a_full_disk_stops_and_records_the_outcome(tmp_path: Path) -> None:
    """The run's Ds log hits a full disk mid-sweep: the motor is stopped and verified, the run
    ends in a one-line error (not an internal one), and the sidecar says how and why."""
    import thrustmap.rig.devices.opening as opening
    from thrustmap.core.clock import SimClock
    from thrustmap.rig import plans
    from thrustmap.rig.interlocks import Limits
    from thrustmap.rig.runner import Runner

    clock = SimClock()
    stand = opening.open_stand("sim://tyto-1585?bench=full&drive_esc=0", clock, kind="tyto-1585")
    with stand:
        fc = opening.open_throttle_output(
            "sim://betaflight?bench=full&rotors=1&protocol=PWM", clock, kind="msp"
        )
        with fc:
            writer = _DiskFillsUp(tmp_path / "run.csv", fc.throttle_scale, {"rotors_on_esc": 1})
            runner = Runner(
                plans.stairs(10, 30, 10, dwell_s=1.0),
                fc,
                stand,
                writer,
                clock,
                limits=Limits(max_current_a=120),
            )
            with pytest.raises(ConfigError, match="cannot write the Ds log after 40 rows"):
                runner.run()
            assert fc.verify_stopped()
    side = stand_recording.read_sidecar(tmp_path / "run.csv")
    assert side is not None and side.status == "aborted" and side.stop_verified is True
    assert "No space left" in side.reason and side.samples == 40
    ds = load_dataset(tmp_path / "run.csv")
    assert len(ds) == 40 and "partial" in ds.meta


def test_step_index_must_be_a_plan_index(tmp_path: Path) -> None:
    p = tmp_path / "run.csv"
    p.write_text("time_s,throttle_pct,thrust_n,voltage_v,step\n0,10,1,16,0\n0.1,10,1,16,1e300\n")
    with pytest.raises(DataFormatError, match=":3: column 'step': expected a plan step index"):
        load_dataset(p)


def test_settled_marks_from_a_real_runner_are_used(tmp_path: Path) -> None:
    """A settling sweep on the simulated bench: the runner marks where each hold settled, and
    selection averages exactly those samples (no second guess)."""
    import thrustmap.rig.devices.opening as devices_opening
    from thrustmap.core.clock import SimClock
    from thrustmap.rig import plans
    from thrustmap.rig.interlocks import Limits
    from thrustmap.rig.runner import record_sweep

    clock = SimClock()
    stand = devices_opening.open_stand(
        "sim://tyto-1585?bench=settle&drive_esc=0", clock, kind="tyto-1585"
    )
    with stand:
        fc = devices_opening.open_throttle_output(
            "sim://betaflight?bench=settle&rotors=1&protocol=PWM", clock, kind="msp"
        )
        with fc:
            plan = plans.stairs(20, 40, 10, dwell_s=6.0, settle=True, record_s=0.8)
            result = record_sweep(
                plan, fc, stand, str(tmp_path / "s.csv"), clock, limits=Limits(max_current_a=120)
            )
    assert result.status == "completed"
    ds = load_dataset(tmp_path / "s.csv")
    assert ds.settled is not None and ds.settled.any() and ds.step is not None
    pts = select(ds, Selection())
    assert pts.report["plateaus_settled_by_recorder"] == 3 and (pts.kind == "plateau").sum() == 3
    for level, thrust in zip((0, 1, 2), pts.thrust_n, strict=True):
        marked = ds.settled & (ds.step == level)
        assert thrust == pytest.approx(float(np.mean(ds.thrust_n[marked])), rel=1e-12)


def test_ds_log_without_recorded_steps_falls_back_to_throttle_plateaus(tmp_path: Path) -> None:
    w = stand_recording.DsWriter(tmp_path / "run.csv", SCALES["pwm"], {})
    for k in range(40):
        w.write(0.05 * k, 1300 + 100 * (k // 20), {"thrust_n": 1.0 + k // 20, "voltage_v": 16.0})
    w.finish("completed")
    ds = load_dataset(tmp_path / "run.csv")
    assert ds.step is None
    assert select(ds, Selection()).report["plateaus"] == 2
