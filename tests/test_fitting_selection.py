"""Steady-state extraction: plateaus, settling, and up/down ramp pairing that cancels rotor lag."""

from __future__ import annotations

import numpy as np

from thrustmap.fitting.dataset import Dataset
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
