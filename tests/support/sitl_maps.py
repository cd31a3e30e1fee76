"""Stand maps for the simulators' own motors (for the real-SITL `gamma live` tests).

A stand map of a SITL vehicle's motor is what its physics says a thrust stand would measure:

- ArduCopter SITL (its built-in quad, libraries/SITL/SIM_Frame and SIM_Motor): per motor
  T = ½ρA·v², v = (V/V_max)·v_max·√((1−e)·c + e·c²), with the command c = (pwm − pwm_lo)/(pwm_hi −
  pwm_lo) between MOT_SPIN_MIN and MOT_SPIN_MAX of the 1000..2000 µs range, e = 0.65, V_max =
  12.6 V, and v_max set so that the 3 kg quad hovers at c = 0.39 on a full battery: T =
  (m·g/4)·(V/12.6)²·((1−e)c + e·c²)/0.39. Fitted here with thrustmap's motor model.
- PX4 SIH quadx (simulator_sih): per motor T = SIH_T_MAX·u, u in 0..1 (SIH_T_MAX = 5 N), no
  voltage effect: a linear model.

Neither map is the flight's own motor: that would leave γ = 1 with nothing to correct (and the
no-worse check keeps the map uncorrected). As a real stand map would, each differs from the
vehicle in flight: the ArduCopter map was "measured" at sea level (air density 1.225 kg/m³)
while SITL flies at its field's 584 m (ISA 1.157 kg/m³), so the stand saw 5.9 % more thrust;
the PX4 map's motor reached 5.5 N on the stand (a prop in free air, not under the frame) where
SIH's reaches 5 N. γ(B) is then about 1.06 and 1.10.
"""

from __future__ import annotations

import numpy as np

from thrustmap.core.units import SCALES, ThrottleScale
from thrustmap.fitting.mapfile import Box, ThrustMap, ValidityBox

G0 = 9.80665
AP_MASS_KG = 3.0
AP_EXPO, AP_SPIN_MIN, AP_SPIN_MAX, AP_V_MAX, AP_HOVER_CMD = 0.65, 0.15, 0.95, 12.6, 0.39
PX4_MASS_KG = 1.0
PX4_T_MAX_N = 5.0
PX4_STAND_T_MAX_N = 5.5
#: ISA density at sea level over that at ArduPilot's test field (584 m)
AP_STAND_DENSITY_RATIO = 1.225 / 1.1568


def ardupilot_thrust_n(
    throttle_pct: np.ndarray, voltage_v: np.ndarray, density_ratio: float = 1.0
) -> np.ndarray:
    pwm = 1000.0 + 10.0 * throttle_pct
    lo = 1000.0 + AP_SPIN_MIN * 1000.0
    hi = 1000.0 + AP_SPIN_MAX * 1000.0
    c = np.clip((pwm - lo) / (hi - lo), 0.0, 1.0)
    shape = (1 - AP_EXPO) * c + AP_EXPO * c**2
    hover_n = AP_MASS_KG * G0 / 4.0
    return np.asarray(
        density_ratio * hover_n * (voltage_v / AP_V_MAX) ** 2 * shape / AP_HOVER_CMD, float
    )


def ardupilot_map() -> ThrustMap:
    """The motor model fitted to the SITL motor at sea level, 20..90 % throttle, 10.5..12.6 V."""
    th, b = np.meshgrid(np.linspace(20.0, 90.0, 36), np.linspace(10.5, 12.6, 8))
    th, b = th.ravel(), b.ravel()
    t = ardupilot_thrust_n(th, b, AP_STAND_DENSITY_RATIO)
    ok = t > 0.05
    th, b, t = th[ok], b[ok], t[ok]
    from scipy.optimize import lsq_linear

    a = np.column_stack([np.ones_like(t), 1 / b, np.sqrt(t) / b, t / b])
    sol = lsq_linear(a, th, bounds=([-20, 0, 0, 0], [50, np.inf, np.inf, np.inf]))
    return ThrustMap(
        model="motor",
        coefficients=tuple(float(x) for x in sol.x),
        throttle_scale=SCALES["pwm"],
        validity=ValidityBox(Box(0.0, float(t.max())), Box(10.5, 12.6), Box(20.0, 90.0)),
        strategy="SR",
        created_utc="2026-01-01T00:00:00+00:00",
    )


def px4_map() -> ThrustMap:
    return ThrustMap(
        model="linear",
        coefficients=(0.0, 100.0 / PX4_STAND_T_MAX_N),
        throttle_scale=ThrottleScale("pwm", 1000.0, 2000.0, "us"),
        validity=ValidityBox(Box(0.0, PX4_STAND_T_MAX_N), Box(10.0, 17.0), Box(0.0, 100.0)),
        strategy="SR",
        created_utc="2026-01-01T00:00:00+00:00",
    )
