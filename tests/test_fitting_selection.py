"""Steady-state extraction: plateaus, settling, and up/down ramp pairing that cancels rotor lag."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from thrustmap.cli import main
from thrustmap.fitting.dataset import STEP_SUMMARY, Dataset
from thrustmap.fitting.loaders import load_dataset
from thrustmap.fitting.selection import Selection, plateaus, select
from thrustmap.units import SCALES


def lagged(throttle_us: np.ndarray, dt_s: float, tau_s: float) -> tuple[np.ndarray, np.ndarray]:
    """True steady thrust, and what a rotor with first-order lag ``tau_s`` produces."""
    u = (throttle_us - 1000) / 1000
    steady = 12.0 * u**2
    out = np.empty_like(steady)
    out[0] = steady[0]
    a = np.exp(-dt_s / tau_s)
    for k in range(1, len(steady)):
        out[k] = steady[k] + (out[k - 1] - steady[k]) * a
    return steady, out


def ramp_dataset(rate_us_s: float = 50.0, dt_s: float = 0.05, tau_s: float = 0.15) -> Dataset:
    up = np.arange(1100, 1700, rate_us_s * dt_s)
    throttle = np.concatenate(
        [np.full(40, 1100.0), up, np.full(40, 1700.0), up[::-1], np.full(40, 1100.0)]
    )
    _, thrust = lagged(throttle, dt_s, tau_s)
    n = len(throttle)
    return Dataset(
        path="ramp.csv",
        format="synthetic",
        throttle_scale=SCALES["pwm"],
        throttle_native=throttle,
        thrust_n=thrust,
        voltage_v=np.full(n, 22.0),
        line=np.arange(n, dtype=np.int64) + 2,
        time_s=np.arange(n) * dt_s,
    )


def test_ramp_pairs_cancel_rotor_lag() -> None:
    ds = ramp_dataset()
    pts = select(ds, Selection())
    pair = pts.kind == "ramp-pair"
    assert pair.sum() > 50 and pts.report["ramp_pair_points"] == int(pair.sum())
    true = 12.0 * ((ds.throttle_scale.from_pct(pts.throttle_pct[pair]) - 1000) / 1000) ** 2
    paired_err = np.abs(pts.thrust_n[pair] - true).mean()
    # the up-ramp alone lags: compare the raw up-ramp samples against the truth
    steady, lag = lagged(ds.throttle_native, 0.05, 0.15)
    rising = np.gradient(ds.throttle_native) > 0
    raw_err = np.abs(lag[rising] - steady[rising]).mean()
    assert paired_err < 0.1 * raw_err, (paired_err, raw_err)
    # the hold levels still come out as plateaus, with the settling dropped
    assert (pts.kind == "plateau").sum() == 3


def test_fast_transitions_between_steps_are_not_paired() -> None:
    step = np.repeat([1100.0, 1300.0, 1100.0, 1500.0, 1100.0], 30)
    throttle = np.convolve(step, np.ones(5) / 5, mode="same")  # 0.2 s transitions, not ramps
    _, thrust = lagged(throttle, 0.05, 0.05)
    n = len(throttle)
    ds = Dataset(
        path="s.csv",
        format="synthetic",
        throttle_scale=SCALES["pwm"],
        throttle_native=throttle,
        thrust_n=thrust,
        voltage_v=np.full(n, 22.0),
        line=np.arange(n, dtype=np.int64) + 2,
        time_s=np.arange(n) * 0.05,
    )
    pts = select(ds, Selection())
    assert pts.report["ramp_pair_points"] == 0
    assert (pts.kind == "plateau").sum() == 5


def test_plateaus_split_on_command_changes_only() -> None:
    th = np.array([10.0] * 5 + [10.01] * 3 + [12.0] * 6)
    assert plateaus(th, 0.05) == [(0, 8), (8, 14)]


# -- step-summary exports (one averaged row per throttle step) --------------------------------

STEP_HEADER = (
    "Time (s),ESC signal (µs),Servo 1 (µs),Servo 2 (µs),Servo 3 (µs),Thrust (gf),Voltage (V),"
    "Current (A),Motor Electrical Speed (RPM),Motor Optical Speed (RPM),Electrical Power (W),"
    "Overall Efficiency (gf/W),App message,"
)


def _step_summary(path: Path, dt_s: float = 1.7, repeat: int = 1) -> Path:
    rows = []
    k = 0
    for i, us in enumerate(range(1050, 2001, 95)):
        for _ in range(repeat):
            thrust_gf = 300.0 * ((us - 1000) / 1000) ** 2
            rows.append(
                f"{k * dt_s:.3f},{us},,,,{thrust_gf:.3f},{7.4 - 0.02 * i:.3f},{0.4 + i},"
                f"{3000 + 1200 * i},0,10,3,,"
            )
            k += 1
    path.write_text("\ufeff" + "\n".join([STEP_HEADER, *rows]) + "\n", encoding="utf-8")
    return path


def test_step_summary_detected_and_every_row_is_a_point(tmp_path: Path) -> None:
    ds = load_dataset(_step_summary(tmp_path / "s_7.csv"))
    assert ds.meta["layout"] == STEP_SUMMARY
    pts = select(ds, Selection())
    assert len(pts) == 11 and set(pts.kind.tolist()) == {"step-summary"}
    assert pts.report["step_summary_rows"] == 11
    assert pts.thrust_n[-1] == pytest.approx(300.0 * 9.80665e-3)
    # the same levels logged continuously (each command repeated at the logging rate) are not
    for dt, rep in ((0.12, 8), (1.7, 2)):
        cont = load_dataset(_step_summary(tmp_path / f"c{rep}.csv", dt_s=dt, repeat=rep))
        assert "layout" not in cont.meta


def test_step_summary_said_by_inspect(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    p = _step_summary(tmp_path / "s_7.csv")
    main(["inspect", str(p)])
    out = capsys.readouterr().out
    assert "layout: step-summary (one averaged row per throttle step" in out
    assert "'step_summary_rows': 11" in out


def test_real_step_summaries_give_points_by_default(shared_data: Path) -> None:
    folder = shared_data / "third-party-stands" / "strawson-5inch"
    files = sorted(folder.glob("*.csv"))
    assert len(files) == 96
    for f in files:
        ds = load_dataset(f)
        assert ds.meta.get("layout") == STEP_SUMMARY, f
        pts = select(ds, Selection())
        assert len(pts) >= 9, (f, pts.report)
    # the stand's own continuous logs (steps, ramps, re-saved) are not step summaries
    for f in sorted((shared_data / "xnova-thrust-stand").glob("*/*.csv")):
        assert "layout" not in load_dataset(f).meta, f
