"""The simulator's physics: determinism, dynamics, battery, ground truth and realism."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from thrustmap.core.errors import ConfigError
from thrustmap.rig.sim.physics import (
    PhysicsPlant,
    cell_ocv_v,
    make_plant,
    operating_point,
    true_throttle_fraction,
    true_thrust_n,
)
from thrustmap.rig.sim.plant import Plant, PlantState
from thrustmap.rig.sim.presets import PRESETS, XNOVA_2207_6S

XNOVA = "xnova-2207-6s"
CF = "crazyflie-2.1"


def _all(plant: PhysicsPlant, fraction: float, time_s: float) -> None:
    for m in range(plant.motor_count):
        plant.set_throttle(m, fraction, time_s)


def _settle(plant: PhysicsPlant, fraction: float, duration_s: float = 1.0) -> PlantState:
    _all(plant, fraction, plant.time_s)
    return plant.state(plant.time_s + duration_s)


def test_is_a_plant_and_presets_listed() -> None:
    plant: Plant = make_plant(XNOVA, rotors_on_esc=4, seed=0)
    assert plant.motor_count == 4
    assert set(PRESETS) == {XNOVA, CF}


def test_unknown_preset_and_parameter_are_clear_errors() -> None:
    with pytest.raises(ConfigError, match="known presets: crazyflie-2.1, xnova-2207-6s"):
        make_plant("t-motor", rotors_on_esc=1, seed=0)
    with pytest.raises(ConfigError, match="unknown plant parameter.*kv_rpm"):
        make_plant(XNOVA, rotors_on_esc=1, seed=0, kv_rpm=1.0)
    with pytest.raises(ConfigError, match="rotors_on_esc"):
        make_plant(XNOVA, rotors_on_esc=0, seed=0)
    with pytest.raises(ConfigError, match="esc_curve"):
        make_plant(
            XNOVA,
            rotors_on_esc=1,
            seed=0,
            esc_curve=((0.0, 0.0), (0.5, 0.6), (0.7, 0.5), (1.0, 1.0)),
        )


def test_time_never_goes_backwards_and_motor_index_checked() -> None:
    plant = make_plant(XNOVA, rotors_on_esc=1, seed=0)
    plant.state(1.0)
    with pytest.raises(ValueError, match="backwards"):
        plant.state(0.5)
    with pytest.raises(ValueError, match="motor 1"):
        plant.set_throttle(1, 0.5, 1.0)


def test_the_timeline_starts_when_the_plant_is_first_told() -> None:
    """A wall clock reads the machine's uptime: a plant behind a sim:// URL must not integrate
    a rest from 0 to it (hours of simulated time: seconds to minutes of CPU before the stand's
    first reading, which made sweeps against a real FC miss their at-rest wait)."""
    plant = make_plant(XNOVA, rotors_on_esc=1, seed=0)
    first = plant.state(3600.0)
    assert first.time_s == 3600.0 and plant.time_s == 3600.0
    assert plant.soc == plant.params.initial_soc  # at rest until now: nothing drawn
    assert first.rpm == [0.0]
    plant.set_throttle(0, 0.5, 3600.0)
    assert plant.state(3601.0).rpm[0] > 1000.0  # from then on, integrated as always
    fixed = make_plant(XNOVA, rotors_on_esc=1, seed=0, start_time_s=0.0)
    fixed.state(60.0)
    assert fixed.soc < fixed.params.initial_soc  # a given origin is kept: the ESC idles 60 s


def _trace(seed: int) -> list[PlantState]:
    plant = make_plant(XNOVA, rotors_on_esc=4, seed=seed)
    out = []
    for k in range(60):
        t = 0.05 * k
        if k % 20 == 0:
            _all(plant, 0.2 + 0.01 * k, t)
        out.append(plant.state(t))
    return out


def test_deterministic_for_a_seed() -> None:
    a, b, c = _trace(7), _trace(7), _trace(8)
    assert a == b
    assert [s.thrust_n for s in a] != [s.thrust_n for s in c]
    # Only the sensor noise depends on the seed, not the physics.
    assert [s.motor_thrust_n for s in a] == [s.motor_thrust_n for s in c]


def test_rotor_lag_time_constant() -> None:
    p = XNOVA_2207_6S
    plant = make_plant(XNOVA, rotors_on_esc=1, seed=0, noise=False)
    start = _settle(plant, 0.4, 2.0)
    t0 = plant.time_s
    plant.set_throttle(0, 0.5, t0)
    times = t0 + np.arange(1, 400) * 0.001
    rpm = np.array([plant.state(t).rpm[0] for t in times])
    final = plant.state(t0 + 1.0).rpm[0]
    frac = (rpm - start.rpm[0]) / (final - start.rpm[0])
    tau_s = float(times[np.argmax(frac >= 1 - math.exp(-1))] - t0)
    omega = final * 2 * math.pi / 60
    kv = p.kv_rad_per_s_per_v
    # The battery and the bus are in series with the winding, seen through the duty (0.5^2).
    r_series = p.internal_resistance_ohm * (
        1 + p.low_soc_resistance_gain * math.exp(-plant.soc / 0.12)
    )
    r_eff = p.winding_resistance_ohm + 0.25 * (r_series + p.bus_resistance_ohm)
    expected_s = p.rotor_inertia_kg_m2 / (1 / (kv * kv * r_eff) + 2 * p.torque_coeff_nm_s2 * omega)
    assert 0.030 <= tau_s <= 0.080
    assert tau_s == pytest.approx(expected_s, rel=0.08)
    assert frac[9] > 0.15  # it responds at once (first order, no dead time)


def test_sag_four_rotors_on_the_esc() -> None:
    sags, currents = {}, {}
    for n in (1, 4):
        plant = make_plant(XNOVA, rotors_on_esc=n, seed=0, noise=False, initial_soc=0.6)
        ocv = plant.ocv_v
        s = _settle(plant, 0.45, 1.0)
        sags[n] = ocv - s.voltage_v
        currents[n] = s.current_a
    assert 0.15 < sags[1] < 0.5
    assert 3.3 < sags[4] / sags[1] < 4.2
    assert 3.3 < currents[4] / currents[1] < 4.1


def test_mr_needs_more_throttle_than_sr_at_the_same_measured_voltage() -> None:
    thrust = np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    sr = true_throttle_fraction(XNOVA_2207_6S, 1, thrust, 22.0)
    mr = true_throttle_fraction(XNOVA_2207_6S, 4, thrust, 22.0)
    assert np.all(mr > sr)
    assert 0.002 < float(mr[-1] - sr[-1]) < 0.03


def test_battery_drains() -> None:
    plant = make_plant(XNOVA, rotors_on_esc=1, seed=0, noise=False, initial_soc=0.8)
    first = _settle(plant, 0.6, 2.0)
    soc0, mah0 = plant.soc, plant.consumed_mah
    currents = []
    for k in range(1, 601):
        currents.append(plant.state(2.0 + 0.1 * k).current_a)
    last = plant.state(62.0)
    drawn_mah = float(np.mean(currents)) * 60.0 / 3.6
    assert plant.consumed_mah - mah0 == pytest.approx(drawn_mah, rel=0.01)
    assert soc0 - plant.soc == pytest.approx(drawn_mah / XNOVA_2207_6S.capacity_mah, rel=0.01)
    assert 0.10 < soc0 - plant.soc < 0.25  # ~12 A for a minute from a 1300 mAh pack
    assert last.voltage_v < first.voltage_v - 0.2
    assert last.thrust_n < first.thrust_n  # same throttle, lower voltage
    assert last.temperature_c[0] > first.temperature_c[0] > XNOVA_2207_6S.ambient_c


def test_battery_ocv_curve() -> None:
    assert float(cell_ocv_v(1.0)) == pytest.approx(4.2)
    assert float(cell_ocv_v(0.0)) == pytest.approx(3.3)
    assert np.all(np.diff(cell_ocv_v(np.linspace(0, 1, 101))) > 0)
    assert make_plant(XNOVA, rotors_on_esc=1, seed=0, initial_soc=1.0).ocv_v == pytest.approx(25.2)
    for soc in (0.0, 0.03, 0.5, 0.77, 1.0):
        plant = make_plant(CF, rotors_on_esc=1, seed=0, initial_soc=soc)
        assert plant.ocv_v == pytest.approx(float(cell_ocv_v(soc)), abs=1e-12)


@pytest.mark.parametrize("name", [XNOVA, CF])
@pytest.mark.parametrize("rotors", [1, 4])
def test_truth_inverse_is_identity(name: str, rotors: int) -> None:
    p = PRESETS[name]
    volts = p.cells * np.linspace(3.5, 4.2, 8)
    u, v = np.meshgrid(np.linspace(0.12, 1.0, 45), volts)
    op = operating_point(p, rotors, u, v)
    back = true_throttle_fraction(p, rotors, op.thrust_n, v)
    # Where the ESC current limit holds the rotors back, more throttle gives no more thrust.
    free = op.battery_current_a < p.esc_current_limit_a
    assert free.mean() > (0.5 if (name == XNOVA and rotors == 4) else 0.999)
    np.testing.assert_allclose(back[free], u[free], atol=1e-6)
    assert np.all(back[~free] <= u[~free])
    thrust = op.thrust_n
    # ...and the other way round, vectorised over thrust.
    t_grid = np.linspace(0.05, 0.9, 30) * float(np.nanmax(thrust))
    u_back = true_throttle_fraction(p, rotors, t_grid, volts[-1])
    ok = np.isfinite(u_back)
    np.testing.assert_allclose(
        true_thrust_n(p, rotors, u_back[ok], volts[-1]), t_grid[ok], rtol=1e-9
    )


def test_truth_is_nan_where_unreachable() -> None:
    p = XNOVA_2207_6S
    assert np.isnan(true_throttle_fraction(p, 1, 100.0, 22.0))  # beyond full throttle
    assert np.isnan(true_throttle_fraction(p, 4, 9.0, 22.0))  # beyond the 65 A ESC limit
    assert np.isfinite(true_throttle_fraction(p, 1, 9.0, 22.0))
    assert float(true_thrust_n(p, 1, 0.02, 22.0)) == 0.0  # below the ESC start threshold


@pytest.mark.parametrize(("rotors", "fraction"), [(1, 0.35), (1, 0.8), (4, 0.5), (4, 0.85)])
def test_dynamic_plant_settles_onto_the_truth(rotors: int, fraction: float) -> None:
    """What a stand records (T, B, Th) after settling lies on the truth, whatever the battery."""
    # A battery that holds still (no polarization, huge capacity): the plant lands exactly on it.
    still = make_plant(
        XNOVA,
        rotors_on_esc=rotors,
        seed=0,
        noise=False,
        initial_soc=0.7,
        polarization_resistance_ohm=0.0,
        capacity_mah=1e9,
    )
    _settle(still, fraction * 0.5, 1.0)
    # On the current limit the rotors are power-limited and settle slowly (tau ~ 0.4 s).
    s = _settle(still, fraction, 8.0)
    assert s.thrust_n == pytest.approx(float(still.true_thrust_n(fraction, s.voltage_v)), rel=1e-7)
    assert s.current_a <= XNOVA_2207_6S.esc_current_limit_a + 1e-9
    if s.current_a < XNOVA_2207_6S.esc_current_limit_a - 1e-6:
        assert float(still.true_throttle_fraction(s.thrust_n, s.voltage_v)) == pytest.approx(
            fraction, abs=1e-7
        )
    steady = still.steady_state(fraction, soc=still.soc)
    assert steady.thrust_n == pytest.approx(s.thrust_n, rel=1e-6)
    assert steady.voltage_v == pytest.approx(s.voltage_v, rel=1e-6)
    assert steady.current_a == pytest.approx(s.current_a, rel=1e-5)
    # The real battery keeps sagging; the rotors follow it with their ~50 ms lag.
    plant = make_plant(XNOVA, rotors_on_esc=rotors, seed=0, noise=False, initial_soc=0.7)
    _settle(plant, fraction * 0.5, 1.0)
    s = _settle(plant, fraction, 2.0)
    assert s.thrust_n == pytest.approx(float(plant.true_thrust_n(fraction, s.voltage_v)), rel=2e-3)


def _poll(rate_hz: float) -> list[PlantState]:
    plant = make_plant(XNOVA, rotors_on_esc=4, seed=3, noise=False)
    schedule = {0.0: 0.3, 0.5: 0.7, 2.0: 0.15, 3.3: 0.55, 4.0: 0.0}
    out = []
    for k in range(int(5.0 * rate_hz) + 1):
        t = k / rate_hz
        for t_set, u in schedule.items():
            if abs(t - t_set) < 1e-9:
                _all(plant, u, t)
        if abs(t * 10 - round(t * 10)) < 1e-9:
            out.append(plant.state(t))
        else:
            plant.state(t)
    return out


def test_polling_rate_does_not_change_the_result() -> None:
    slow, fast = _poll(10.0), _poll(1000.0)
    assert len(slow) == len(fast) == 51
    for a, b in zip(slow, fast, strict=True):
        assert a.time_s == pytest.approx(b.time_s, abs=1e-9)
        assert a.thrust_n == pytest.approx(b.thrust_n, rel=1e-4, abs=1e-5)
        assert a.voltage_v == pytest.approx(b.voltage_v, rel=1e-5)
        assert a.current_a == pytest.approx(b.current_a, rel=1e-3, abs=1e-3)
        np.testing.assert_allclose(a.rpm, b.rpm, rtol=1e-4, atol=0.5)
        np.testing.assert_allclose(a.temperature_c, b.temperature_c, rtol=1e-5)


def test_motor_stops_when_throttle_is_cut() -> None:
    plant = make_plant(XNOVA, rotors_on_esc=1, seed=0, noise=False)
    spinning = _settle(plant, 0.5, 1.0)
    assert spinning.rpm[0] > 15000
    plant.set_throttle(0, 0.0, plant.time_s)
    assert 0 < plant.state(plant.time_s + 0.5).rpm[0] < spinning.rpm[0]
    assert plant.state(plant.time_s + 5.0).rpm[0] == 0.0


def test_load_cell_noise_drift_and_vibration() -> None:
    p = XNOVA_2207_6S
    plant = make_plant(XNOVA, rotors_on_esc=1, seed=11)
    idle = plant.state(1.0)
    assert idle.vibration_g < 0.2
    s = _settle(plant, 0.5, 1.0)
    states = [plant.state(s.time_s + 0.01 * k) for k in range(1, 2001)]
    error = np.array([x.thrust_n - x.motor_thrust_n[0] for x in states])
    assert s.motor_thrust_n[0] > 3.0 and s.thrust_n > 0  # pulling is positive
    assert float(np.std(error)) == pytest.approx(p.thrust_noise_n, rel=0.1)
    assert abs(float(np.mean(error))) < p.drift_n + 0.002
    assert abs(plant.drift_n(300.0)) <= p.drift_n and plant.drift_n(0.0) != plant.drift_n(150.0)
    fast = _settle(plant, 0.9, 1.0)
    assert fast.vibration_g > s.vibration_g > idle.vibration_g
    expected = p.vibration_floor_g + p.vibration_g_per_krpm2 * (fast.rpm[0] / 1000) ** 2
    assert expected <= fast.vibration_g < expected + 5 * p.vibration_noise_g


# -- realism: the xNova preset against the seed paper's single-rotor stand data ---------------
# (ESC us, measured terminal voltage V, measured thrust N, measured current A), read from
# xNova-SR-steps-up.csv (plateau means) and xNova-SR-ramp.csv (at 1800 us, tare removed).
REAL_SR_POINTS = [
    (1300, 22.469, 1.401, 2.093),
    (1500, 21.860, 3.972, 7.724),
    (1600, 21.216, 5.313, 11.912),
    (1800, 21.172, 9.026, 25.216),
]


@pytest.mark.parametrize(("us", "volts", "thrust", "current"), REAL_SR_POINTS)
def test_xnova_sr_curve_matches_the_real_stand(
    us: int, volts: float, thrust: float, current: float
) -> None:
    u = (us - 1000) / 1000
    plant = make_plant(XNOVA, rotors_on_esc=1, seed=0, noise=False)
    assert float(plant.true_thrust_n(u, volts)) == pytest.approx(thrust, rel=0.04)
    # In thrust-map terms: the throttle the truth needs for the real (T, B) is within 6 us.
    assert float(plant.true_throttle_fraction(thrust, volts)) == pytest.approx(u, abs=0.006)
    op = operating_point(XNOVA_2207_6S, 1, u, volts)
    assert float(op.battery_current_a) == pytest.approx(current, rel=0.05)


def test_xnova_sag_at_full_current_is_a_volt_or_two() -> None:
    plant = make_plant(XNOVA, rotors_on_esc=1, seed=0, noise=False)
    s = plant.steady_state(0.8, soc=0.3)
    assert 23.0 < s.current_a < 28.0
    assert 0.8 < plant.steady_state(0.0, soc=0.3).voltage_v - s.voltage_v < 2.5


def _plateaus(path: Path) -> pd.DataFrame:
    frame = pd.read_csv(path, encoding="utf-8-sig")
    frame = pd.DataFrame(
        {
            "time_s": frame["Time (s)"],
            "us": frame["ESC signal (µs)"],
            "thrust_n": -frame["Thrust (N)"],
            "voltage_v": frame["Voltage (V)"],
            "current_a": frame["Current (A)"],
        }
    )
    segment = (frame["us"].diff().abs() > 0.5).cumsum()
    rows = []
    for _, seg in frame.groupby(segment):
        if seg["time_s"].iloc[-1] - seg["time_s"].iloc[0] < 0.8 or seg["us"].iloc[0] < 1140:
            continue
        rows.append(seg.iloc[len(seg) // 2 :].mean())  # second half: the rotor has settled
    return pd.DataFrame(rows)


@pytest.mark.parametrize(
    ("relpath", "rotors", "thrust_rel", "throttle_abs"),
    [
        ("single_rotor/xNova-SR-steps-up.csv", 1, 0.04, 0.006),
        ("single_rotor/xNova-SR-steps.csv", 1, 0.04, 0.010),  # a nearly empty pack
        ("multirotor/xNova-MR-steps.csv", 4, 0.06, 0.010),  # not used for tuning
    ],
)
def test_xnova_against_every_real_plateau(
    shared_data: Path, relpath: str, rotors: int, thrust_rel: float, throttle_abs: float
) -> None:
    real = _plateaus(shared_data / "xnova-thrust-stand" / relpath)
    assert len(real) >= 9
    u = (real["us"].to_numpy() - 1000) / 1000
    volts = real["voltage_v"].to_numpy()
    sim = true_thrust_n(XNOVA_2207_6S, rotors, u, volts)
    rel = sim / real["thrust_n"].to_numpy() - 1
    assert np.max(np.abs(rel)) < thrust_rel, rel
    back = true_throttle_fraction(XNOVA_2207_6S, rotors, real["thrust_n"].to_numpy(), volts)
    assert np.max(np.abs(back - u)) < throttle_abs


def test_crazyflie_preset() -> None:
    plant = make_plant(CF, rotors_on_esc=4, seed=0, noise=False, initial_soc=1.0)
    assert plant.ocv_v == pytest.approx(4.2)
    full = plant.steady_state(1.0, soc=1.0)
    total_g = 4 * full.thrust_n / 9.81 * 1000
    assert 55 < total_g < 66  # ~60 g from four motors
    assert 3.4 < full.voltage_v < 3.9  # 1S under ~4 A
    # The seed paper's command 60000 of 65535: the plant fraction is cmd / 65535.
    at_60000 = plant.steady_state(60000 / 65535, soc=1.0)
    assert 0.85 < at_60000.thrust_n / full.thrust_n < 0.97
    hover = float(plant.true_throttle_fraction(0.027 * 9.81 / 4, 3.9))  # 27 g vehicle
    assert 0.4 < hover < 0.65
