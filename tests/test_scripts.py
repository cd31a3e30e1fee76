"""The bench scripts in scripts/ run end to end on the simulator (SimClock) and write Ds logs
that load, with the levels each experiment is meant to visit, in order."""

from __future__ import annotations

import importlib.util
import json
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from thrustmap.fitting.loaders.load import load_dataset
from thrustmap.rig.sim import peers

SCRIPTS = Path(__file__).resolve().parent.parent / "scripts"


@pytest.fixture(autouse=True)
def fresh_bench() -> Iterator[None]:
    peers.reset_benches()
    yield
    peers.reset_benches()


def load_script(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(f"bench_script_{name}", SCRIPTS / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def plateaus(throttle: np.ndarray, min_samples: int = 20) -> list[float]:
    """Throttle levels held for at least ``min_samples`` consecutive samples, in order."""
    edges = np.flatnonzero(np.diff(throttle) != 0) + 1
    runs = np.split(throttle, edges)
    return [float(r[0]) for r in runs if len(r) >= min_samples]


def run(name: str, tmp_path: Path, *extra: str) -> tuple[object, Path]:
    out = tmp_path / f"{name}.csv"
    result = load_script(name).main(["-o", str(out), "--yes", *extra])
    assert result is not None
    assert result.status == "completed", result.reason
    assert result.stop_verified
    return result, out


def test_steps_visits_each_step_and_returns_low(tmp_path: Path) -> None:
    _, out = run("steps", tmp_path)
    ds = load_dataset(out)
    assert ds.format == "thrustmap"
    assert ds.meta["outcome"]["status"] == "completed"
    assert ds.throttle_scale.lo == 1000 and ds.throttle_scale.hi == 2000  # PWM, as the paper
    assert ds.rotors_on_esc == 1
    expected = [1100.0]
    for level in range(1150, 1601, 50):
        expected += [float(level), 1100.0]
    assert plateaus(ds.throttle_native) == expected
    # thrust rises with the step level (the sim rotor really spun)
    top = ds.thrust_n[ds.throttle_native == 1600]
    low = ds.thrust_n[ds.throttle_native == 1100]
    assert np.median(top) > 5.0 > 1.0 > np.median(low) > 0.05


@pytest.mark.parametrize(("name", "descending"), [("stairs_up", False), ("stairs_down", True)])
def test_stairs_visit_levels_in_order(tmp_path: Path, name: str, descending: bool) -> None:
    _, out = run(name, tmp_path)
    ds = load_dataset(out)
    levels = [float(v) for v in range(1100, 1601, 50)]
    assert plateaus(ds.throttle_native) == (levels[::-1] if descending else levels)
    meta = json.loads(out.with_suffix(".meta.json").read_text())
    assert meta["plan"]["name"] == ("stairs-down" if descending else "stairs-up")


def test_ramp_goes_up_to_the_top_and_back(tmp_path: Path) -> None:
    _, out = run("ramp", tmp_path)
    ds = load_dataset(out)
    th = ds.throttle_native
    peak = int(np.argmax(th))
    assert th.max() == 1700
    assert np.all(np.diff(th[: peak + 1]) >= 0)  # up, never back
    assert np.all(np.diff(th[peak:]) <= 0)  # down, never up
    assert th[-1] <= 1010  # back at the bottom (the stop follows)
    assert len(np.unique(th)) > 200  # a ramp, not a few steps


def test_settle_and_stand_esc_options_through_the_constants(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An edited script: settle detection on, the stand driving the ESC itself."""
    mod = load_script("stairs_up")
    monkeypatch.setattr(mod, "SETTLE", True)  # as a user edits the constants
    monkeypatch.setattr(mod, "TO_PCT", 30.0)
    out = tmp_path / "edited.csv"
    result = mod.main(
        ["--stand", "sim://tyto-1585?bench=esc", "--throttle", "stand", "-o", str(out), "--yes"]
    )
    assert result is not None and result.status == "completed" and result.stop_verified
    fixed_s = len(mod.plan().segments) * mod.DWELL_S
    assert result.duration_s < fixed_s  # holds ended once thrust settled
    ds = load_dataset(out)
    assert plateaus(ds.throttle_native, 10) == [1100.0, 1150.0, 1200.0, 1250.0, 1300.0]


def test_declining_the_prompt_spins_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr("builtins.input", lambda prompt="": "n")
    out = tmp_path / "never.csv"
    assert load_script("steps").main(["-o", str(out)]) is None
    assert not out.exists()
    assert "nothing spun" in capsys.readouterr().out


def test_adaptive_stops_at_its_target_and_records_why(tmp_path: Path) -> None:
    result, out = run("adaptive", tmp_path)
    assert result.reason.startswith("target met")  # type: ignore[attr-defined]
    ds = load_dataset(out)
    assert ds.meta["outcome"]["status"] == "completed"
    meta = json.loads(out.with_suffix(".meta.json").read_text(encoding="utf-8"))
    points = meta["adaptive"]["points"]
    assert [round(p["throttle_pct"], 1) for p in points[:5]] == [10.0, 22.5, 35.0, 47.5, 60.0]
    assert len(points) > 5 and all(p["pi_after_pct"] is not None for p in points[5:])
