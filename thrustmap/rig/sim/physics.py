"""The physics behind every simulated peer: ESC, motors, propellers, battery and load cell.

Model (averaged, per motor i, all rotors on one ESC and one battery):

- ESC: duty d_i = curve(u_i) ** exponent for u_i >= start fraction (curve: the preset's
  piecewise-linear ``esc_curve``), else the output is off and the rotor coasts (friction + drag). If the battery-side current would exceed the ESC limit, every duty is scaled down
  so that it does not (the seed paper's 65 A ESC with four rotors at high throttle).
- Bus: V_term = OCV(soc) - V_pol - I_batt * R_int(soc) is what the stand's voltage sensor reads;
  the motors see V_bus = V_term - I_batt * R_bus (shared wires/ESC bus, unseen by the sensor).
  I_batt = sum(d_i * I_i) + I_quiescent. With N rotors on the ESC the current and both drops
  are N times larger: at the same *measured* voltage the MR map needs more throttle than SR.
- Motor: d_i * V_bus - drop = w_i / Kv + I_i * R (``esc_drop_v``: what the ESC's switches
  take while driving, 0 unless a preset or override sets it); rotor J dw/dt = (I_i - I0) / Kv - kq w^2. With the
  bus voltage frozen over a substep this is a Riccati equation, integrated exactly, so the
  rotor lag costs one exp per step. Its time constant is J / (1/(Kv^2 R_eff) + 2 kq w) with
  R_eff = R + d^2 N (R_batt + R_bus): 40-55 ms for the xNova preset. On the ESC current limit
  the rotors are power-limited and settle more slowly (~0.4 s).
- Propeller: T = kt w^2, Q = kq w^2. Battery: soc drains with I_batt, the polarization
  voltage and motor temperatures follow exact first-order updates; a held load discharges
  the pack (its open-circuit voltage follows the LiPo table), and ``connect_pack`` swaps it
  for another (refused while a motor is commanded or turning).
- Load cell (motor 0): thrust + slow deterministic drift + Gaussian noise; pulling = positive.
  A creeping load cell (``LoadCellCreep``, ``creeping_reading``) shows part of a load change
  late: the system-id staircases (``rig.sim.sysid``) use it.

Time is injected: ``state(t)`` integrates up to ``t`` with substeps of at most
``max_substep_s`` while a rotor is in transient and ``settled_substep_s`` once all have settled,
so results do not depend on how often the plant is polled. The timeline starts at the first time
the plant is told (at rest until then) unless ``start_time_s`` fixes it: a wall clock's origin is
the machine's boot. Randomness comes from one seeded ``numpy.random.Generator``.

Ground truth (``true_thrust_n`` / ``true_throttle_fraction``) is the steady state with all
``rotors_on_esc`` rotors at the same throttle, expressed in the *measured terminal voltage*
(what a Ds triplet (T, B, Th) records as B), so it does not depend on the battery's state.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from thrustmap.core.errors import ConfigError, SafetyError
from thrustmap.rig.sim.plant import PlantState
from thrustmap.rig.sim.presets import LIPO_OCV_CELL_V, LIPO_OCV_SOC, PlantParams
from thrustmap.rig.sim.presets import preset as get_preset

FloatArray = NDArray[np.float64]
_SETTLED_REL = 2e-4  # a rotor is settled when |w - w_target| < this * no-load speed
_BISECT_STEPS = 60


def cell_ocv_v(soc: ArrayLike) -> FloatArray:
    """Open-circuit voltage of one LiPo cell at state of charge ``soc`` (0..1)."""
    return np.asarray(np.interp(np.clip(soc, 0.0, 1.0), LIPO_OCV_SOC, LIPO_OCV_CELL_V), dtype=float)


def soc_from_cell_ocv(cell_v: ArrayLike) -> FloatArray:
    """Inverse of ``cell_ocv_v`` (the table is monotonic)."""
    return np.asarray(
        np.interp(np.asarray(cell_v, dtype=float), LIPO_OCV_CELL_V, LIPO_OCV_SOC), dtype=float
    )


def internal_resistance_ohm(params: PlantParams, soc: float) -> float:
    return params.internal_resistance_ohm * (
        1.0 + params.low_soc_resistance_gain * math.exp(-soc / 0.12)
    )


def duty_from_throttle(params: PlantParams, fraction: ArrayLike) -> FloatArray:
    """ESC duty for a throttle fraction, before any current limiting (0 where the ESC is off)."""
    u = np.clip(np.asarray(fraction, dtype=float), 0.0, 1.0)
    on = (u >= params.esc_start_fraction) & (u > 0.0)
    curve = np.interp(u, [k[0] for k in params.esc_curve], [k[1] for k in params.esc_curve])
    return np.where(on, curve**params.esc_duty_exponent, 0.0)


def throttle_from_duty(params: PlantParams, duty: ArrayLike) -> FloatArray:
    """Inverse of ``duty_from_throttle``; NaN where no throttle gives that duty."""
    d = np.asarray(duty, dtype=float)
    curve = np.where(d >= 0, np.abs(d) ** (1.0 / params.esc_duty_exponent), np.nan)
    curve = np.where(curve <= 1.0 + 1e-9, np.minimum(curve, 1.0), np.nan)  # rounding at full
    knots_u = [k[0] for k in params.esc_curve]
    u = np.interp(curve, [k[1] for k in params.esc_curve], knots_u)
    return np.where(np.isfinite(curve) & (u >= params.esc_start_fraction), u, np.nan)


@dataclass(frozen=True)
class OperatingPoint:
    """Steady state of identical rotors at one measured terminal voltage (arrays broadcast)."""

    omega_rad_s: FloatArray
    duty: FloatArray  # after current limiting
    motor_current_a: FloatArray  # winding current of one motor
    battery_current_a: FloatArray  # total, all rotors + quiescent
    bus_voltage_v: FloatArray
    thrust_n: FloatArray  # per rotor


def operating_point(
    params: PlantParams, rotors: int, throttle: ArrayLike, voltage_v: ArrayLike
) -> OperatingPoint:
    """Steady state with ``rotors`` rotors at ``throttle`` while the sensor reads ``voltage_v``."""
    kv, r, rw, i0 = (
        params.kv_rad_per_s_per_v,
        params.winding_resistance_ohm,
        params.bus_resistance_ohm,
        params.no_load_current_a,
    )
    kq, iq, lim = params.torque_coeff_nm_s2, params.esc_quiescent_a, params.esc_current_limit_a
    drop = params.esc_drop_v
    u, v = np.broadcast_arrays(
        np.asarray(throttle, dtype=float), np.asarray(voltage_v, dtype=float)
    )
    d = duty_from_throttle(params, u)
    # Unlimited: (R + Rw N d^2) I + w/Kv = d (V - Rw Iq), I = I0 + kq Kv w^2: a quadratic in w.
    r_eff = r + rw * rotors * d * d
    c = r_eff * i0 - d * (v - rw * iq) + np.where(d > 0, drop, 0.0)
    a = r_eff * kq * kv
    omega = np.where(c < 0, -2.0 * c / (1.0 / kv + np.sqrt(1.0 / kv**2 - 4.0 * a * c)), 0.0)
    i_m = np.where(d > 0, i0 + kq * kv * omega**2, 0.0)
    i_b = rotors * d * i_m + iq
    limited = i_b > lim
    if np.any(limited):
        # The ESC holds I_batt = limit: V_bus is known, solve N I(w) (w/Kv + R I(w)) = (lim - Iq) V_bus.
        v_bus = v - rw * lim
        hi = np.where(limited, omega, 0.0)
        lo = np.zeros_like(hi)
        for _ in range(_BISECT_STEPS):
            mid = 0.5 * (lo + hi)
            im = i0 + kq * kv * mid**2
            over = rotors * im * (mid / kv + r * im + drop) > (lim - iq) * v_bus
            hi, lo = np.where(over, mid, hi), np.where(over, lo, mid)
        w_lim = 0.5 * (lo + hi)
        im_lim = i0 + kq * kv * w_lim**2
        omega = np.where(limited, w_lim, omega)
        i_m = np.where(limited, im_lim, i_m)
        d = np.where(limited, (w_lim / kv + r * im_lim + drop) / np.maximum(v_bus, 1e-9), d)
        i_b = np.where(limited, lim, i_b)
    return OperatingPoint(
        omega_rad_s=omega,
        duty=d,
        motor_current_a=i_m,
        battery_current_a=i_b,
        bus_voltage_v=v - rw * i_b,
        thrust_n=params.thrust_coeff_n_s2 * omega**2,
    )


def true_thrust_n(
    params: PlantParams, rotors: int, throttle_fraction: ArrayLike, voltage_v: ArrayLike
) -> FloatArray:
    """Steady per-rotor thrust at ``throttle_fraction`` with the sensor reading ``voltage_v``."""
    return operating_point(params, rotors, throttle_fraction, voltage_v).thrust_n


def true_throttle_fraction(
    params: PlantParams, rotors: int, thrust_n: ArrayLike, voltage_v: ArrayLike
) -> FloatArray:
    """Steady throttle that makes ``thrust_n`` per rotor while the sensor reads ``voltage_v``.

    NaN where no throttle does: above the maximum (duty > 1 or the ESC current limit) or
    between zero and the thrust at the ESC start threshold.
    """
    kv, r, rw, i0 = (
        params.kv_rad_per_s_per_v,
        params.winding_resistance_ohm,
        params.bus_resistance_ohm,
        params.no_load_current_a,
    )
    t, v = np.broadcast_arrays(
        np.asarray(thrust_n, dtype=float), np.asarray(voltage_v, dtype=float)
    )
    omega = np.sqrt(np.maximum(t, 0.0) / params.thrust_coeff_n_s2)
    i_m = i0 + params.torque_coeff_nm_s2 * kv * omega**2
    c = omega / kv + r * i_m + params.esc_drop_v  # = d * V_bus
    vq = v - rw * params.esc_quiescent_a
    # Rw N I d^2 - vq d + c = 0, smaller root (the larger one is a collapsed bus).
    disc = vq**2 - 4.0 * rw * rotors * i_m * c
    with np.errstate(invalid="ignore"):
        d = 2.0 * c / (vq + np.sqrt(disc))
    i_b = rotors * d * i_m + params.esc_quiescent_a
    ok = (disc >= 0) & (t >= 0) & (i_b <= params.esc_current_limit_a * (1 + 1e-12))
    return np.where(ok, throttle_from_duty(params, np.where(ok, d, np.nan)), np.nan)


class PhysicsPlant:
    """A ``Plant``: ``rotors_on_esc`` motors on one ESC and battery, motor 0 on the load cell.

    The per-substep arithmetic runs on Python floats per motor: with one to eight motors that
    is several times faster than numpy's per-call overhead (see benchmarks/bench_sim.py).
    """

    def __init__(
        self,
        params: PlantParams,
        *,
        rotors_on_esc: int,
        rng: np.random.Generator,
        start_time_s: float | None = None,
    ):
        if rotors_on_esc < 1:
            raise ConfigError(f"rotors_on_esc must be >= 1, got {rotors_on_esc}")
        params.validate()
        self.params = params
        self.rotors_on_esc = rotors_on_esc
        self._rng = rng
        n = rotors_on_esc
        # None: the timeline starts at the first time the plant is told (a wall clock reads
        # the machine's uptime: integrating from 0 to it, at rest, took seconds to minutes)
        self._t = 0.0 if start_time_s is None else float(start_time_s)
        self._origin_pending = start_time_s is None
        self._throttle = [0.0] * n
        self._duty_cmd = [0.0] * n  # ESC duty for the throttle, before current limiting
        self._omega = [0.0] * n
        self._temp = [params.ambient_c] * n
        self.soc = params.initial_soc
        self._v_pol = 0.0
        self._charge_c = 0.0  # drawn so far, coulombs
        self._energy_j = 0.0  # drawn so far at the pack's terminals (every pack connected)
        self.packs_connected = 1
        self._settled = True
        phases = rng.uniform(0.0, 2.0 * math.pi, size=2)
        self._drift_phase = (float(phases[0]), float(phases[1]))
        self._kv = params.kv_rad_per_s_per_v

    # -- Plant protocol ---------------------------------------------------------------------
    @property
    def motor_count(self) -> int:
        return self.rotors_on_esc

    def set_throttle(self, motor: int, fraction: float, time_s: float) -> None:
        if not 0 <= motor < self.rotors_on_esc:
            raise ValueError(f"motor {motor} out of range 0..{self.rotors_on_esc - 1}")
        self._advance(time_s)
        value = min(max(float(fraction), 0.0), 1.0) if math.isfinite(fraction) else 0.0
        if value != self._throttle[motor]:
            self._throttle[motor] = value
            self._duty_cmd[motor] = float(duty_from_throttle(self.params, value))
            self._settled = False

    def state(self, time_s: float) -> PlantState:
        self._advance(time_s)
        p, rng, kv, r = self.params, self._rng, self._kv, self.params.winding_resistance_ohm
        duty, v_bus, i_batt, v_term = self._electrics(self._emf_v(), self._r_batt())
        drop = p.esc_drop_v
        batt_a = [
            d * (d * v_bus - drop - w / kv) / r if d > 0 else 0.0
            for d, w in zip(duty, self._omega, strict=True)
        ]
        thrust = [p.thrust_coeff_n_s2 * w * w for w in self._omega]
        rpm = [w * 60.0 / (2.0 * math.pi) for w in self._omega]
        vib = p.vibration_floor_g + p.vibration_g_per_krpm2 * (rpm[0] / 1000.0) ** 2
        noise = rng.standard_normal(3)
        return PlantState(
            time_s=self._t,
            voltage_v=v_term,
            current_a=i_batt,
            thrust_n=thrust[0] + self.drift_n(self._t) + p.thrust_noise_n * float(noise[0]),
            torque_nm=p.torque_coeff_nm_s2 * self._omega[0] ** 2
            + p.torque_noise_nm * float(noise[1]),
            rpm=rpm,
            motor_current_a=batt_a,
            temperature_c=list(self._temp),
            vibration_g=vib + p.vibration_noise_g * abs(float(noise[2])),
            motor_thrust_n=thrust,
        )

    # -- extras -------------------------------------------------------------------------------
    @property
    def time_s(self) -> float:
        return self._t

    @property
    def ocv_v(self) -> float:
        return _cell_ocv_scalar(self.soc) * self.params.cells

    @property
    def consumed_mah(self) -> float:
        return self._charge_c / 3.6

    @property
    def drawn_wh(self) -> float:
        """Energy drawn at the pack's terminals so far, every pack connected included."""
        return self._energy_j / 3600.0

    def connect_pack(
        self,
        time_s: float,
        *,
        soc: float | None = None,
        ocv_v: float | None = None,
        cells: int | None = None,
    ) -> None:
        """Swap the battery at ``time_s`` for a rested pack at ``soc`` or open-circuit voltage
        ``ocv_v`` (``cells``: a pack of another cell count). Refused while any motor is
        commanded or still turning: a pack is not swapped under load."""
        self._advance(time_s)
        if any(u > 0.0 for u in self._throttle) or any(w > 1e-3 * self._kv for w in self._omega):
            raise SafetyError("a battery is not swapped while a motor is commanded or turning")
        if (soc is None) == (ocv_v is None):
            raise ConfigError("connect_pack needs exactly one of soc= or ocv_v=")
        if cells is not None and cells != self.params.cells:
            if cells < 1:
                raise ConfigError(f"a pack needs at least one cell, got {cells}")
            self.params = replace(self.params, cells=cells)
        if soc is None:
            assert ocv_v is not None
            soc = float(soc_from_cell_ocv(ocv_v / self.params.cells))
        if not 0.0 <= soc <= 1.0:
            raise ConfigError(f"state of charge must be in 0..1, got {soc}")
        self.soc = float(soc)
        self._v_pol = 0.0
        self.packs_connected += 1

    def drift_n(self, time_s: float) -> float:
        """The load cell's slow zero drift at ``time_s`` (deterministic for a seed)."""
        p = self.params
        w = 2.0 * math.pi / p.drift_period_s
        a, b = self._drift_phase
        return p.drift_n * (math.sin(w * time_s + a) + 0.5 * math.sin(2.7 * w * time_s + b)) / 1.5

    def true_thrust_n(self, throttle_fraction: ArrayLike, voltage_v: ArrayLike) -> FloatArray:
        """Ground truth for this plant's ``rotors_on_esc`` (see module ``true_thrust_n``)."""
        return true_thrust_n(self.params, self.rotors_on_esc, throttle_fraction, voltage_v)

    def true_throttle_fraction(self, thrust_n: ArrayLike, voltage_v: ArrayLike) -> FloatArray:
        """Ground truth for this plant's ``rotors_on_esc`` (see module ``true_throttle_fraction``)."""
        return true_throttle_fraction(self.params, self.rotors_on_esc, thrust_n, voltage_v)

    def steady_state(
        self, throttle_fraction: float, *, soc: float | None = None, ocv_v: float | None = None
    ) -> PlantState:
        """Noise-free steady state, every rotor at ``throttle_fraction``, battery at ``soc`` or
        pack open-circuit voltage ``ocv_v`` (held; polarization at equilibrium)."""
        p = self.params
        if (soc is None) == (ocv_v is None):
            raise ConfigError("steady_state needs exactly one of soc= or ocv_v=")
        if soc is None:
            assert ocv_v is not None
            soc = float(soc_from_cell_ocv(ocv_v / p.cells))
        ocv = _cell_ocv_scalar(soc) * p.cells
        r_series = internal_resistance_ohm(p, soc) + p.polarization_resistance_ohm
        lo, hi = 0.0, ocv  # V_term = OCV - I(V_term) * R is monotonic: bisect
        for _ in range(_BISECT_STEPS):
            mid = 0.5 * (lo + hi)
            op = operating_point(p, self.rotors_on_esc, throttle_fraction, mid)
            if mid > ocv - float(op.battery_current_a) * r_series:
                hi = mid
            else:
                lo = mid
        op = operating_point(p, self.rotors_on_esc, throttle_fraction, 0.5 * (lo + hi))
        w, im, d = float(op.omega_rad_s), float(op.motor_current_a), float(op.duty)
        loss = im * im * p.winding_resistance_ohm + (
            p.no_load_current_a * w / self._kv if d > 0 else 0.0
        )
        n, rpm = self.rotors_on_esc, w * 60.0 / (2.0 * math.pi)
        return PlantState(
            time_s=self._t,
            voltage_v=0.5 * (lo + hi),
            current_a=float(op.battery_current_a),
            thrust_n=float(op.thrust_n),
            torque_nm=p.torque_coeff_nm_s2 * w * w,
            rpm=[rpm] * n,
            motor_current_a=[d * im] * n,
            temperature_c=[p.ambient_c + loss * p.thermal_resistance_k_per_w] * n,
            vibration_g=p.vibration_floor_g + p.vibration_g_per_krpm2 * (rpm / 1000.0) ** 2,
            motor_thrust_n=[float(op.thrust_n)] * n,
        )

    # -- integration --------------------------------------------------------------------------
    def _advance(self, time_s: float) -> None:
        if self._origin_pending:
            self._origin_pending = False
            self._t = float(time_s)  # at rest until now: nothing to integrate
            return
        if time_s < self._t - 1e-9:
            raise ValueError(f"plant time cannot go backwards: {time_s} < {self._t}")
        p = self.params
        while self._t < time_s:
            h = min(p.settled_substep_s if self._settled else p.max_substep_s, time_s - self._t)
            self._step(h)
            self._t += h
            if time_s - self._t < 1e-12:
                self._t = max(self._t, time_s)

    def _emf_v(self) -> float:
        return self.ocv_v - self._v_pol

    def _r_batt(self) -> float:
        return internal_resistance_ohm(self.params, self.soc)

    def _electrics(self, e_v: float, r_batt: float) -> tuple[list[float], float, float, float]:
        """Duty after current limiting, V_bus, I_batt and V_term for the present rotor speeds."""
        p = self.params
        r, kv, iq, r_s = (
            p.winding_resistance_ohm,
            self._kv,
            p.esc_quiescent_a,
            r_batt + p.bus_resistance_ohm,
        )
        duty = self._duty_cmd
        a = sum(d * d for d in duty) / r
        b = sum(d * (w / kv + p.esc_drop_v) for d, w in zip(duty, self._omega, strict=True)) / r
        v_bus = (e_v + r_s * (b - iq)) / (1.0 + r_s * a)
        i_b = a * v_bus - b + iq
        if i_b > p.esc_current_limit_a:
            # Scale every duty by s so that I_batt = limit: a V s^2 - b s - (lim - iq) = 0.
            v_bus = e_v - r_s * p.esc_current_limit_a
            need = p.esc_current_limit_a - iq
            s = (
                (b + math.sqrt(b * b + 4.0 * a * v_bus * need)) / (2.0 * a * v_bus)
                if v_bus > 0
                else 0.0
            )
            duty = [d * min(s, 1.0) for d in duty]
            i_b = p.esc_current_limit_a
        return duty, v_bus, i_b, v_bus + i_b * p.bus_resistance_ohm

    def _step(self, h: float) -> None:
        p = self.params
        kv, r, j = self._kv, p.winding_resistance_ohm, p.rotor_inertia_kg_m2
        duty, v_bus, i_b, v_term = self._electrics(self._emf_v(), self._r_batt())
        self._energy_j += v_term * i_b * h
        # Rotor: dw/dt = P - Q w - Rr w^2, exact for the bus voltage frozen over the substep.
        # With the ESC off (no electrical path) P = -friction, Q = 0: the rotor coasts to a stop.
        rr = p.torque_coeff_nm_s2 / j
        friction = p.no_load_current_a / (kv * j)
        q_on = 1.0 / (kv * kv * r * j)
        tolerance = _SETTLED_REL * kv * self.ocv_v
        settled = True
        cool = math.exp(-h / p.thermal_time_s)
        for m, (d, w0) in enumerate(zip(duty, self._omega, strict=True)):
            pp, qq = (
                ((d * v_bus - p.esc_drop_v) / (kv * r * j) - friction, q_on)
                if d > 0
                else (-friction, 0.0)
            )
            disc = qq * qq + 4.0 * pp * rr
            if qq > 0.0 and disc > 1e-9 * qq * qq:
                lam = math.sqrt(disc)
                w_hi, w_lo = (lam - qq) / (2.0 * rr), (-lam - qq) / (2.0 * rr)
                z = (w0 - w_hi) / (w0 - w_lo) * math.exp(-lam * h)
                w1 = max((w_hi - z * w_lo) / (1.0 - z), 0.0)
                settled = settled and abs(w1 - max(w_hi, 0.0)) < tolerance
            else:  # dw/dt = -c - Rr w^2: w = tan(atan(w0 k) - c k h) / k, k = sqrt(Rr / c)
                c = max(-pp, 1e-12)
                k = math.sqrt(rr / c)
                w1 = math.tan(max(math.atan(w0 * k) - c * k * h, 0.0)) / k
            self._omega[m] = w1
            # Heating: copper loss and iron/friction loss (I0 x back-EMF), exact first order.
            w_mid = 0.5 * (w0 + w1)
            i_m = (d * v_bus - p.esc_drop_v - w_mid / kv) / r if d > 0 else 0.0
            loss = i_m * i_m * r + (p.no_load_current_a * w_mid / kv if d > 0 else 0.0)
            t_eq = p.ambient_c + loss * p.thermal_resistance_k_per_w
            self._temp[m] = t_eq + (self._temp[m] - t_eq) * cool
        self._settled = settled
        # Battery: charge drawn, state of charge, polarization (exact RC).
        self._charge_c += i_b * h
        self.soc = max(0.0, self.soc - i_b * h / (3.6 * p.capacity_mah))
        v_pol_eq = i_b * p.polarization_resistance_ohm
        self._v_pol = v_pol_eq + (self._v_pol - v_pol_eq) * math.exp(-h / p.polarization_time_s)


def _cell_ocv_scalar(soc: float) -> float:
    """``cell_ocv_v`` for one float, without numpy's per-call overhead."""
    x = min(max(soc, 0.0), 1.0)
    i = min(bisect.bisect_right(LIPO_OCV_SOC, x), len(LIPO_OCV_SOC) - 1)
    x0, x1 = LIPO_OCV_SOC[i - 1], LIPO_OCV_SOC[i]
    y0, y1 = LIPO_OCV_CELL_V[i - 1], LIPO_OCV_CELL_V[i]
    return y0 + (y1 - y0) * (x - x0) / (x1 - x0)


@dataclass(frozen=True)
class LoadCellCreep:
    """A creeping load cell: of a change in load, ``fraction`` shows at once and the rest
    arrives over ``time_s`` (first order), as the strain gauges' glue and the beam relax. Under a
    constant load the reading drifts toward the load; calibrated with weights left on, a
    settled reading is the load. A staircase reads low on its way up and high on its way down,
    by more than the rotors lag."""

    fraction: float = 0.10  # share of a load change that arrives late
    time_s: float = 3.0  # its time constant


def creeping_reading(force_n: ArrayLike, step_s: float, creep: LoadCellCreep) -> FloatArray:
    """What a creeping load cell reads of ``force_n`` sampled every ``step_s`` (the force held
    over each step): F − fraction·(F − F_slow), F_slow the force through a first-order lag of
    ``creep.time_s`` (exact for a piecewise-constant force), starting settled at the first
    sample."""
    f: FloatArray = np.asarray(force_n, dtype=float)
    if f.size == 0 or creep.fraction == 0.0:
        return np.array(f, dtype=float)
    a = math.exp(-step_s / max(creep.time_s, 1e-12))
    slow = np.empty_like(f)
    s = float(f[0])
    for k, x in enumerate(f.tolist()):
        s = x + (s - x) * a
        slow[k] = s
    out: FloatArray = np.asarray(f - creep.fraction * (f - slow), dtype=float)
    return out


def make_plant(
    preset: str,
    *,
    rotors_on_esc: int,
    seed: int,
    noise: bool = True,
    start_time_s: float | None = None,
    **overrides: Any,
) -> PhysicsPlant:
    """A plant from a named preset (see ``PRESETS``), e.g. ``make_plant("xnova-2207-6s",
    rotors_on_esc=4, seed=1)``. ``noise=False`` turns sensor noise and drift off; keyword
    overrides replace preset fields (``initial_soc=0.5``, ``esc_current_limit_a=40``, ...)."""
    params = get_preset(preset)
    known = {f.name for f in fields(PlantParams)} - {"name"}
    unknown = sorted(set(overrides) - known)
    if unknown:
        raise ConfigError(
            f"unknown plant parameter(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}"
        )
    if not noise:
        overrides = {
            "thrust_noise_n": 0.0,
            "torque_noise_nm": 0.0,
            "drift_n": 0.0,
            "vibration_noise_g": 0.0,
            **overrides,
        }
    params = replace(params, **overrides)
    return PhysicsPlant(
        params,
        rotors_on_esc=rotors_on_esc,
        rng=np.random.default_rng(seed),
        start_time_s=start_time_s,
    )


__all__ = [
    "LoadCellCreep",
    "OperatingPoint",
    "PhysicsPlant",
    "cell_ocv_v",
    "creeping_reading",
    "duty_from_throttle",
    "make_plant",
    "operating_point",
    "soc_from_cell_ocv",
    "throttle_from_duty",
    "true_throttle_fraction",
    "true_thrust_n",
]
