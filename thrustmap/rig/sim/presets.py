"""Parameter sets for the simulated propulsion plant (``rig.sim.physics``).

Every number is in SI units except where the name says otherwise (``kv_rpm_per_v``,
``capacity_mah``, ``*_c``). A preset is a frozen ``PlantParams``; ``make_plant`` in
``rig.sim.physics`` builds a plant from one, optionally with fields overridden.

``xnova-2207-6s`` is tuned against the seed paper's single-rotor stand data
(published with the paper: xNova 2207-2100Kv, 5" prop, Foxeer Reaper 65 A ESC,
TATTU R-Line 6S): kt, kq, I0 and the ESC curve by least squares on the SR plateaus (thrust and
current at the measured voltage), Kv and R nominal. At the measured voltage the steady SR thrust
is within 3.4 % of every real SR plateau (1150-1800 us) and the MR data, not used for the fit,
within 4.7 %; see tests/test_sim_physics.py.
``crazyflie-2.1`` follows the Crazyflie seed paper and Bitcraze's published figures (7x16 mm
brushed coreless motors on a 1S 250 mAh LiPo, about 60 g of thrust from four motors).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from itertools import pairwise

from thrustmap.core.errors import ConfigError

# Open-circuit voltage of one LiPo cell over state of charge (resting, room temperature).
LIPO_OCV_SOC: tuple[float, ...] = (
    0.0,
    0.05,
    0.10,
    0.15,
    0.20,
    0.30,
    0.40,
    0.50,
    0.60,
    0.70,
    0.80,
    0.90,
    1.0,
)
LIPO_OCV_CELL_V: tuple[float, ...] = (
    3.30,
    3.55,
    3.65,
    3.69,
    3.72,
    3.76,
    3.79,
    3.82,
    3.86,
    3.92,
    4.00,
    4.09,
    4.20,
)


@dataclass(frozen=True)
class PlantParams:
    """One propulsion set: ESC, motor, propeller, battery, heating and the load cell."""

    name: str
    # ESC: throttle fraction u (0..1) -> duty d. Below esc_start_fraction the output is off
    # (the motor coasts); above, d = curve(u) ** esc_duty_exponent, where curve is the
    # piecewise-linear esc_curve (increasing (u, d) knots from (0, 0) to (1, 1)); the current
    # limit scales it down further.
    esc_start_fraction: float
    esc_duty_exponent: float
    esc_current_limit_a: float  # total battery-side current the ESC delivers (inf = none)
    esc_quiescent_a: float  # ESC/FC electronics draw
    # Shared path from the stand's voltage sense point to the motors (wires, ESC bus): every
    # rotor on the ESC adds to the drop here, the voltage sensor does not see it.
    bus_resistance_ohm: float
    # BLDC (or brushed) motor, averaged: d*V_bus = w/Kv + I*R, torque = (I - I0)/Kv.
    kv_rpm_per_v: float
    winding_resistance_ohm: float  # per motor, including the ESC FETs
    no_load_current_a: float
    rotor_inertia_kg_m2: float  # motor bell + propeller
    # Propeller: T = kt*w^2, Q = kq*w^2 (w in rad/s).
    thrust_coeff_n_s2: float
    torque_coeff_nm_s2: float
    prop_diameter_m: float
    # Battery pack.
    cells: int
    capacity_mah: float
    internal_resistance_ohm: float  # pack, ohmic, at high state of charge
    low_soc_resistance_gain: float  # R = R0 * (1 + gain * exp(-soc / 0.12))
    polarization_resistance_ohm: float  # slow sag: RC branch
    polarization_time_s: float
    initial_soc: float
    # Heating of each motor/ESC channel: first order in copper + iron loss.
    ambient_c: float
    thermal_resistance_k_per_w: float
    thermal_time_s: float
    # Load cell and sensors (motor 0 is on the load cell).
    thrust_noise_n: float  # Gaussian, rms
    torque_noise_nm: float
    drift_n: float  # amplitude of the slow zero drift
    drift_period_s: float
    vibration_floor_g: float
    vibration_g_per_krpm2: float  # vibration = floor + k * (rpm/1000)^2 (+ noise)
    vibration_noise_g: float
    esc_curve: tuple[tuple[float, float], ...] = ((0.0, 0.0), (1.0, 1.0))
    # Voltage the ESC's switches take from the motor's supply while driving (FET and diode
    # drops, dead time): d*V_bus - drop = w/Kv + I*R. It makes throttle scale with voltage in
    # a way a map measured at one voltage cannot see (a voltage term k0 = 100 * drop).
    esc_drop_v: float = 0.0
    # Integration: substep while a rotor is in transient / once every rotor has settled.
    max_substep_s: float = 0.001
    settled_substep_s: float = 0.02

    @property
    def kv_rad_per_s_per_v(self) -> float:
        return self.kv_rpm_per_v * 2.0 * math.pi / 60.0

    def validate(self) -> None:
        positive = [
            "kv_rpm_per_v",
            "winding_resistance_ohm",
            "rotor_inertia_kg_m2",
            "thrust_coeff_n_s2",
            "torque_coeff_nm_s2",
            "capacity_mah",
            "esc_duty_exponent",
            "esc_current_limit_a",
            "polarization_time_s",
            "thermal_time_s",
            "drift_period_s",
            "max_substep_s",
            "settled_substep_s",
        ]
        for key in positive:
            if not getattr(self, key) > 0:
                raise ConfigError(f"plant parameter {key} must be > 0, got {getattr(self, key)}")
        if self.cells < 1:
            raise ConfigError(f"plant parameter cells must be >= 1, got {self.cells}")
        if not 0.0 <= self.initial_soc <= 1.0:
            raise ConfigError(
                f"plant parameter initial_soc must be in 0..1, got {self.initial_soc}"
            )
        if not 0.0 <= self.esc_start_fraction < 1.0:
            raise ConfigError(
                f"plant parameter esc_start_fraction must be in [0, 1), got {self.esc_start_fraction}"
            )
        us = [k[0] for k in self.esc_curve]
        ds = [k[1] for k in self.esc_curve]
        if (
            len(self.esc_curve) < 2
            or us[0] != 0.0
            or us[-1] != 1.0
            or ds[0] != 0.0
            or ds[-1] != 1.0
            or any(b <= a for a, b in pairwise(us))
            or any(b <= a for a, b in pairwise(ds))
        ):
            raise ConfigError(
                "plant parameter esc_curve must be strictly increasing (u, duty) knots from "
                f"(0, 0) to (1, 1), got {self.esc_curve}"
            )
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, float) and (math.isnan(value) or value < 0):
                raise ConfigError(f"plant parameter {f.name} must be >= 0, got {value}")


XNOVA_2207_6S = PlantParams(
    name="xnova-2207-6s",
    esc_start_fraction=0.04,  # the real motor starts between 1040 and 1070 us
    esc_duty_exponent=1.0,
    esc_current_limit_a=65.0,  # Foxeer Reaper F4 65 A (the paper: too little for 4 rotors at full)
    esc_quiescent_a=0.045,  # measured at 1000 us
    bus_resistance_ohm=0.010,
    kv_rpm_per_v=2100.0,
    winding_resistance_ohm=0.030,
    no_load_current_a=2.12,
    rotor_inertia_kg_m2=3.0e-5,  # gives the ~40 ms lag of motor + ESC response
    thrust_coeff_n_s2=7.49e-7,  # fitted to the SR steps/ramp (CT ~ 0.085 for a 5" prop)
    torque_coeff_nm_s2=1.113e-8,
    prop_diameter_m=0.127,
    cells=6,
    capacity_mah=1300.0,
    internal_resistance_ohm=0.032,
    low_soc_resistance_gain=4.0,
    polarization_resistance_ohm=0.012,
    polarization_time_s=8.0,
    initial_soc=0.95,
    ambient_c=25.0,
    thermal_resistance_k_per_w=0.8,
    thermal_time_s=60.0,
    thrust_noise_n=0.02,
    torque_noise_nm=0.0005,
    drift_n=0.01,
    drift_period_s=600.0,
    vibration_floor_g=0.06,
    vibration_g_per_krpm2=2.5e-4,
    vibration_noise_g=0.03,
    # The ESC's own throttle curve, fitted with the coefficients above to the SR plateaus; the
    # same wiggle (+-3 %) shows in the MR data, which was not used for the fit.
    esc_curve=(
        (0.0, 0.0),
        (0.10, 0.1008),
        (0.15, 0.1514),
        (0.20, 0.2051),
        (0.25, 0.2498),
        (0.30, 0.2898),
        (0.35, 0.3411),
        (0.40, 0.3947),
        (0.45, 0.4498),
        (0.50, 0.5045),
        (0.55, 0.5572),
        (0.60, 0.6056),
        (0.80, 0.8000),
        (1.0, 1.0),
    ),
)

CRAZYFLIE_2_1 = PlantParams(
    name="crazyflie-2.1",
    esc_start_fraction=0.0,  # brushed motors on FETs: duty = cmd/65535, no ESC
    esc_duty_exponent=1.0,
    esc_current_limit_a=math.inf,
    esc_quiescent_a=0.10,  # STM32 + nRF51 + sensors
    bus_resistance_ohm=0.020,  # PCB traces and battery connector
    kv_rpm_per_v=10000.0,
    winding_resistance_ohm=1.5,
    no_load_current_a=0.05,
    rotor_inertia_kg_m2=3.5e-8,
    thrust_coeff_n_s2=3.2e-8,  # ~0.15 N per motor at full on a full battery
    torque_coeff_nm_s2=1.85e-10,  # kq/kt ~ 6 mm
    prop_diameter_m=0.047,
    cells=1,
    capacity_mah=250.0,
    internal_resistance_ohm=0.10,
    low_soc_resistance_gain=4.0,
    polarization_resistance_ohm=0.05,
    polarization_time_s=10.0,
    initial_soc=0.95,
    ambient_c=25.0,
    thermal_resistance_k_per_w=20.0,
    thermal_time_s=30.0,
    thrust_noise_n=0.0005,
    torque_noise_nm=1e-6,
    drift_n=0.0003,
    drift_period_s=300.0,
    vibration_floor_g=0.02,
    vibration_g_per_krpm2=2.0e-4,
    vibration_noise_g=0.01,
)

PRESETS: dict[str, PlantParams] = {p.name: p for p in (XNOVA_2207_6S, CRAZYFLIE_2_1)}


def preset(name: str) -> PlantParams:
    """The preset called ``name``; a ConfigError lists the known ones otherwise."""
    try:
        return PRESETS[name]
    except KeyError:
        known = ", ".join(sorted(PRESETS))
        raise ConfigError(f"unknown plant preset {name!r}; known presets: {known}") from None
