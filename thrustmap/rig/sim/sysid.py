"""A simulated Crazyflie system-id stand: the staircase log its scripts record.

The Crazyflie system-id deck logs one row every 10 ms (no time column): the load cell's weight
of all four motors in grams, the PWM command (0..65535), the battery voltage, the four rpm and
the deck's own supply voltage, current and power. The motors are stepped up then down, one
command per ``dwell_s`` (100 ms): about one load-cell update per step, so the log is a
quasi-static ramp, not a staircase of settled plateaus. The load cell (an HX711-style
converter) integrates the force over each conversion and holds the result until the next one;
the rotors lag the command; a small, worn 1S battery sags under load (3.9 V at rest to about
3.0 V at full).

``simulate_staircase`` runs the ``crazyflie-2.1`` plant (``rig.sim.physics``) with these
overrides and returns the rows and the plant (its ``true_throttle_fraction`` is the truth a map
is checked against); ``write_csv`` writes them in the deck's own format.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from thrustmap.rig.sim.physics import LoadCellCreep, PhysicsPlant, creeping_reading, make_plant

FloatArray = NDArray[np.float64]

G0 = 9.80665
#: Crazyflie motor command full scale (16-bit PWM compare value).
CF_PWM_MAX = 65535
#: A small, worn 1S cell: rests near 3.9 V, sags to about 3.0 V with four motors at full.
SYSID_BATTERY = {
    "initial_soc": 0.72,
    "internal_resistance_ohm": 0.24,
    "polarization_resistance_ohm": 0.08,
    "polarization_time_s": 3.0,
    # the 7x16 mm coreless motor with its 47 mm prop: ~50 ms to settle after a step
    "rotor_inertia_kg_m2": 4.0e-8,
}


@dataclass(frozen=True)
class StaircaseLog:
    """What the deck logged, one row every ``row_s``; ``true_total_n`` is the noise-free force."""

    row_s: float
    pwm: NDArray[np.int64]
    weight_g: FloatArray  # load cell, all four motors, as held between conversions
    vbat_v: FloatArray
    rpm: FloatArray  # (rows, 4)
    current_a: FloatArray
    true_total_n: FloatArray
    plant: PhysicsPlant

    def __len__(self) -> int:
        return len(self.pwm)


def staircase_commands(
    *, levels: int = 40, top_pct: float = 100.0, rest_rows: int = 30, dwell_rows: int = 10
) -> NDArray[np.int64]:
    """PWM per row: ``rest_rows`` at 0, ``levels`` equal steps up to ``top_pct`` and back down
    (the top level once), ``dwell_rows`` rows each, then ``rest_rows`` at 0."""
    up = np.linspace(top_pct / levels, top_pct, levels)
    pct = np.concatenate([up, up[-2::-1]])
    rows = np.concatenate([np.zeros(rest_rows), np.repeat(pct, dwell_rows), np.zeros(rest_rows)])
    return np.asarray(np.round(rows / 100.0 * CF_PWM_MAX), dtype=np.int64)


@dataclass(frozen=True)
class StaircaseSpec:
    """A simulated Crazyflie system-id staircase: ``levels`` equal steps up to ``top_pct`` and
    back, ``dwell_s`` each, logged every ``row_s``; the load cell converts over
    ``cell_update_s`` with ``cell_noise_g`` rms noise, and may creep (``creep``); the plant is
    integrated ``substeps`` times a row."""

    seed: int = 1
    levels: int = 40
    top_pct: float = 100.0
    dwell_s: float = 0.1
    row_s: float = 0.01
    cell_update_s: float = 0.1
    cell_noise_g: float = 0.3
    substeps: int = 10
    creep: LoadCellCreep | None = None


def simulate_staircase(spec: StaircaseSpec | None = None) -> StaircaseLog:
    """Run the up-then-down staircase on a simulated Crazyflie and log it as the deck does.

    The load cell converts over ``cell_update_s`` (the mean force over the conversion, plus
    Gaussian noise of ``cell_noise_g`` rms) and holds the result until the next conversion; its
    clock is free-running (a seeded phase), not tied to the command steps. ``creep``: the load
    cell creeps (part of each load change arrives late, ``rig.sim.physics.LoadCellCreep``)."""
    spec = spec or StaircaseSpec()
    seed, levels, top_pct, dwell_s = spec.seed, spec.levels, spec.top_pct, spec.dwell_s
    row_s, cell_update_s, cell_noise_g = spec.row_s, spec.cell_update_s, spec.cell_noise_g
    substeps, creep = spec.substeps, spec.creep
    dwell_rows = max(1, round(dwell_s / row_s))
    pwm = staircase_commands(levels=levels, top_pct=top_pct, dwell_rows=dwell_rows)
    plant = make_plant("crazyflie-2.1", rotors_on_esc=4, seed=seed, noise=False, **SYSID_BATTERY)
    rng = np.random.default_rng(seed)
    n = len(pwm)
    h = row_s / substeps
    phase_s = float(rng.uniform(0.0, cell_update_s))
    force = np.empty(n * substeps)  # total force of the four motors at each substep
    vbat, cur = np.empty(n), np.empty(n)
    rpm = np.empty((n, 4))
    for k in range(n):
        u = float(pwm[k]) / CF_PWM_MAX
        t0 = k * row_s
        for m in range(4):
            plant.set_throttle(m, u, t0)
        for s in range(substeps):
            st = plant.state(t0 + (s + 1) * h)
            force[k * substeps + s] = sum(st.motor_thrust_n)
        vbat[k], cur[k], rpm[k] = st.voltage_v, st.current_a, st.rpm
    true_total = force[substeps - 1 :: substeps].copy()
    if creep is not None:
        force = creeping_reading(force, h, creep)
    # Load cell: conversions end at phase + j * update; each is the mean force over its window.
    t_sub = (np.arange(n * substeps) + 1) * h
    per = max(1, round(cell_update_s / h))
    held = np.empty(n)
    t_row = (np.arange(n) + 1) * row_s
    ends = np.arange(phase_s, t_row[-1] + cell_update_s, cell_update_s)
    value = np.empty(len(ends))
    for j, te in enumerate(ends):
        i1 = int(np.searchsorted(t_sub, te, side="right"))
        window = force[max(0, i1 - per) : i1]
        mean_n = float(window.mean()) if window.size else 0.0
        value[j] = mean_n / G0 * 1000.0 + cell_noise_g * float(rng.standard_normal())
    last = np.searchsorted(ends, t_row, side="right") - 1
    held = np.where(last >= 0, value[np.clip(last, 0, None)], cell_noise_g * 0.0)
    return StaircaseLog(
        row_s=row_s,
        pwm=pwm,
        weight_g=np.round(held, 3),
        vbat_v=np.round(vbat, 4),
        rpm=np.round(rpm, 1),
        current_a=np.round(cur, 4),
        true_total_n=true_total,
        plant=plant,
    )


def write_csv(log: StaircaseLog, path: Path) -> Path:
    """The deck's CSV: ``weight[g],pwm,vbat[V],rpm1..rpm4,v[V],i[A],p[W]`` (no time column)."""
    lines = ["weight[g],pwm,vbat[V],rpm1,rpm2,rpm3,rpm4,v[V],i[A],p[W]"]
    for k in range(len(log)):
        v, i = float(log.vbat_v[k]), float(log.current_a[k])
        rpms = ",".join(f"{float(r):.1f}" for r in log.rpm[k])
        lines.append(
            f"{float(log.weight_g[k]):.3f},{int(log.pwm[k])},{v:.4f},{rpms},{v:.4f},{i:.4f},"
            f"{v * i:.4f}"
        )
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n", encoding="ascii")
    return path


def lag_ratio(log: StaircaseLog) -> float:
    """Median of (down-leg / up-leg) load-cell reading at equal command (rotor and cell lag)."""
    pwm = log.pwm
    top = int(np.argmax(pwm))
    ratios = []
    for level in np.unique(pwm[pwm > 0.2 * CF_PWM_MAX]):
        rows = np.flatnonzero(pwm == level)
        up, down = rows[rows < top], rows[rows > top]
        if up.size and down.size:
            ratios.append(float(log.weight_g[down].mean() / log.weight_g[up].mean()))
    return float(np.median(ratios)) if ratios else math.nan


__all__ = [
    "CF_PWM_MAX",
    "StaircaseLog",
    "lag_ratio",
    "simulate_staircase",
    "staircase_commands",
    "write_csv",
]
