"""Stand maps for the simulators' own motors (for the real-SITL `gamma live` tests).

A stand map of a SITL vehicle's motor is what its physics says a thrust stand would measure:

- ArduCopter SITL (its built-in quad, libraries/SITL/SIM_Frame and SIM_Motor): per motor
  T = ½ρA·v², v = (V/V_max)·v_max·√((1−e)·c + e·c²), with the command c = (pwm − pwm_lo)/(pwm_hi −
  pwm_lo) between MOT_SPIN_MIN and MOT_SPIN_MAX of the 1000..2000 µs range, e = 0.65, V_max =
  12.6 V, and v_max set so that the 3 kg quad hovers at c = 0.39 on a full battery: T =
  (m·g/4)·(V/12.6)²·((1−e)c + e·c²)/0.39. Fitted here with thrustmap's motor model.
- PX4 SIH quadx (simulator_sih): per motor T = SIH_T_MAX·u, u in 0..1 (SIH_T_MAX = 5 N), no
  voltage effect: the linear model Th = 20·T (% per N).
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


def ardupilot_thrust_n(throttle_pct: np.ndarray, voltage_v: np.ndarray) -> np.ndarray:
    pwm = 1000.0 + 10.0 * throttle_pct
    lo = 1000.0 + AP_SPIN_MIN * 1000.0
    hi = 1000.0 + AP_SPIN_MAX * 1000.0
    c = np.clip((pwm - lo) / (hi - lo), 0.0, 1.0)
    shape = (1 - AP_EXPO) * c + AP_EXPO * c**2
    return np.asarray(
        AP_MASS_KG * G0 / 4.0 * (voltage_v / AP_V_MAX) ** 2 * shape / AP_HOVER_CMD, float
    )


def ardupilot_map() -> ThrustMap:
    """The motor model fitted to the SITL motor between 20 and 90 % throttle, 10.5..12.6 V."""
    th, b = np.meshgrid(np.linspace(20.0, 90.0, 36), np.linspace(10.5, 12.6, 8))
    th, b = th.ravel(), b.ravel()
    t = ardupilot_thrust_n(th, b)
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
        coefficients=(0.0, 100.0 / PX4_T_MAX_N),
        throttle_scale=ThrottleScale("pwm", 1000.0, 2000.0, "us"),
        validity=ValidityBox(Box(0.0, PX4_T_MAX_N), Box(10.0, 17.0), Box(0.0, 100.0)),
        strategy="SR",
        created_utc="2026-01-01T00:00:00+00:00",
    )
