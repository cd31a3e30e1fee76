"""A map across voltage (issue 30 item 4): ``sweep adaptive --across-voltage`` versus a map
measured at one voltage and versus the fixed two-pack plan, on the simulator.

The rig: the xNova 2207 / 5" set on a 6S pack whose ESC takes ``ESC_DROP_V`` from the motor's
supply while driving (FET and diode drops, dead time: ``PlantParams.esc_drop_v``). The stock
presets scale with voltage exactly as the map's physics (1/B), so on them a map measured at one
voltage already carries across voltage (printed too, as the honest control); the drop is the
simulator's stand-in for what makes real motors miss across voltage (the Strawson sets: about
2 % from 2S to 3S). Every run: SR, a fresh pack, the real MSP and Tyto drivers and the runner on
a SimClock, 10..60 % throttle, limits 120 A / 75 %, 6 cells (min 3.3 V per cell).

- single: ``plans.adaptive`` with a target of ``TARGET_PI_PCT`` over the voltages seen (the
  plan as it was: one voltage);
- across, discharge: the same with ``voltage_range_v = (0.90 V0, V0)`` (V0: the pack at rest
  before the run; 15 % below a 6S pack at rest is a nearly empty pack, under the 3.3 V/cell
  limit once loaded): the plan discharges the pack at its top level;
- across-pack: the same with ``discharge=False`` (``--no-discharge``): the plan stops the motor
  and asks for a pack at the voltage it needs; the simulated user connects a 6S pack reading
  what was asked at rest;
- fixed two-pack: the paper's stairs-up + steps on the 6S pack, then again on a 6S pack at
  0.90 V0 at rest, both logs fitted together.

The adaptive runs have sweep's default budget (10 min, 200 points).
Each map is fitted from its Ds logs with the defaults (``fit_map``) and scored against the
simulator's true map at B = 0.85 V0: mean |map - truth| in % throttle over thrusts from the
lowest measured to the highest that 60 % throttle gives at that voltage (and at V0, for the
other end). Bench time is plan time (waiting for rest and taring excluded); energy is what the
packs gave at their terminals.

Acceptance (issue 30): across <= 0.5 % at 0.85 V0, where single misses by more; time and energy
beside the fixed two-pack plan.

Run: python benchmarks/bench_across_voltage.py [seeds, default 2]   (~35 s per seed)
"""

from __future__ import annotations

import logging
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import thrustmap.rig.segments as segments
from thrustmap.core.clock import SimClock
from thrustmap.demo import experiments
from thrustmap.fitting.adaptive import MapChooser
from thrustmap.fitting.fit.fitmap import fit_map
from thrustmap.fitting.loaders.load import load_datasets
from thrustmap.fitting.mapfile import ThrustMap
from thrustmap.fitting.voltages import measured_voltages
from thrustmap.rig import plans
from thrustmap.rig.devices.opening import open_stand, open_throttle_output
from thrustmap.rig.interlocks import Limits
from thrustmap.rig.run_types import RunConfig
from thrustmap.rig.runner import record_sweep
from thrustmap.rig.sim import peers
from thrustmap.rig.sim.physics import PhysicsPlant, make_plant

TARGET_PI_PCT = 1.0
BELOW = 0.15  # the voltage judged: this share below the pack's start
ASKED_BELOW = 0.10  # the range asked: --voltage-range (1 - ASKED_BELOW) V0 : V0
ESC_DROP_V = 1.0
BUDGET_MIN = 10.0  # the adaptive runs' time budget, minutes (sweep's default)
LIMITS = Limits(max_current_a=120.0, max_throttle_pct=75.0, cells=6)
CFG = RunConfig(settle_window_s=0.6)
RIGS = {"6S, ESC drop 1 V": ESC_DROP_V, "6S, stock (no drop)": 0.0}


@dataclass
class Run:
    duration_s: float
    energy_wh: float
    holds: int
    tmap: ThrustMap
    plant: PhysicsPlant
    v0: float
    reason: str = ""


def _bench(seed: int, drop_v: float) -> tuple[str, PhysicsPlant]:
    peers.reset_benches()
    plant = make_plant("xnova-2207-6s", rotors_on_esc=1, seed=seed, esc_drop_v=drop_v)
    spec = {**peers.DEFAULTS, "plant": "xnova-2207-6s", "rotors": "1", "seed": str(seed)}
    peers._benches["b"] = (spec, plant)  # noqa: SLF001 - a benchmark-only preset variant
    return f"bench=b&rotors=1&seed={seed}", plant


def second_pack(plant: PhysicsPlant, ocv_v: float) -> None:
    """The simulated user connects a 6S pack reading ``ocv_v`` at rest (the motor is stopped:
    the plant refuses otherwise)."""
    plant.connect_pack(plant.time_s, ocv_v=ocv_v)


def run(seed: int, drop_v: float, out: Path, which: str) -> Run:
    query, plant = _bench(seed, drop_v)
    v0 = plant.steady_state(0.0, soc=plant.soc).voltage_v
    clock = SimClock()
    fc = open_throttle_output(f"sim://betaflight?{query}&protocol=PWM", clock, kind="msp")
    stand = open_stand("sim://tyto-1585?bench=b&drive_esc=0", clock, kind="tyto-1585")
    exps: list[tuple[str, plans.Plan]]
    if which == "fixed":
        pair = experiments()
        exps = [
            ("stairs-up", pair["stairs-up"]),
            ("steps", pair["steps"]),
            ("swap", plans.explicit([0.0], dwell_s=0.1)),  # marks the pack change below
            ("stairs-up-2", pair["stairs-up"]),
            ("steps-2", pair["steps"]),
        ]
    else:
        across = which.startswith("across")
        rng = (round((1 - ASKED_BELOW) * v0, 2), round(v0, 2)) if across else None

        def connect(change: segments.PackChange) -> bool:
            second_pack(plant, change.wanted_v)  # what the prompt asked for
            return True

        exps = [
            (
                which,
                plans.adaptive(
                    MapChooser(TARGET_PI_PCT, voltage_range_v=rng),
                    10,
                    60,
                    dwell_s=3.0,
                    max_minutes=BUDGET_MIN,
                    voltage_range_v=rng,
                    connect_pack=connect if rng else None,
                    discharge=which != "across-pack",
                ),
            )
        ]
    logs, duration, holds, reason = [], 0.0, 0, ""
    e0 = plant.drawn_wh
    with fc, stand:
        for name, plan in exps:
            if name == "swap":
                clock.sleep_s(10.0)  # the rotor coasts to rest before the pack comes off
                plant.state(clock.now_s())
                second_pack(
                    plant, (1 - ASKED_BELOW) * v0
                )  # between two runs: both motors stopped and verified
                continue
            path = out / f"{seed}-{drop_v:g}-{which}-{name}.csv"
            result = record_sweep(plan, fc, stand, str(path), clock, limits=LIMITS, config=CFG)
            if result.status != "completed":
                raise RuntimeError(f"{which} {name} (seed {seed}) {result.status}: {result.reason}")
            logs.append(path)
            duration += result.duration_s
            holds += len(plan.segments) if plan.adaptive is None else len(plan.adaptive.records)
            reason = result.reason
    tmap = fit_map(load_datasets(logs)).map
    return Run(duration, plant.drawn_wh - e0, holds, tmap, plant, v0, reason)


def error_at_pct(tmap: ThrustMap, plant: PhysicsPlant, voltage_v: float, n: int = 40) -> float:
    """Mean |map - truth| (% throttle) at ``voltage_v`` over thrusts from the lowest measured
    to the highest 60 % throttle gives there."""
    t_top = float(plant.true_thrust_n(0.60, voltage_v))
    t = np.linspace(tmap.validity.thrust_n.lo, t_top, n)
    truth = plant.true_throttle_fraction(t, voltage_v) * 100.0
    ok = np.isfinite(truth)
    b = np.full(int(ok.sum()), voltage_v)
    return float(np.mean(np.abs(tmap.throttle_pct(t[ok], b, corrected=False) - truth[ok])))


def main() -> None:
    logging.disable(logging.WARNING)
    seeds = range(1, 1 + (int(sys.argv[1]) if len(sys.argv) > 1 else 2))
    started = time.perf_counter()
    print(
        f"Maps across voltage on the simulator (xNova 2207 6S, SR, 10..60 %, target "
        f"{TARGET_PI_PCT:g} %), mean of {len(seeds)} seeds;\nerror = mean |map - true map| "
        f"(% throttle) at {100 * (1 - BELOW):.0f} % of the pack's start voltage V0 and at V0"
    )
    head = (
        f"{'rig':<20} {'plan':<15} {'bench time':>10} {'energy':>9} {'holds':>6} "
        f"{'err 0.85V0':>10} {'err V0':>8}  measured at (V)"
    )
    print(head)
    print("-" * len(head))
    verdicts = []
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        for rig, drop in RIGS.items():
            rows: dict[str, list[tuple[float, float, float, float, float]]] = {}
            volts: dict[str, list[tuple[float, float]]] = {}
            for which in ("single", "across", "across-pack", "fixed"):
                for seed in seeds:
                    r = run(seed, drop, out, which)
                    low = error_at_pct(r.tmap, r.plant, (1 - BELOW) * r.v0)
                    top = error_at_pct(r.tmap, r.plant, r.v0)
                    rows.setdefault(which, []).append(
                        (r.duration_s, r.energy_wh, r.holds, low, top)
                    )
                    volts[which] = measured_voltages_of(r.tmap)
                m = np.mean(np.array(rows[which]), axis=0)
                label = {"fixed": "fixed two-pack", "across": "across, discharge"}.get(which, which)
                shown = ", ".join(f"{lo:.1f}..{hi:.1f}" for lo, hi in volts[which])
                print(
                    f"{rig:<20} {label:<15} {m[0]:>8.1f} s {m[1]:>6.2f} Wh {m[2]:>6.1f} "
                    f"{m[3]:>8.3f} % {m[4]:>6.3f} %  {shown}"
                )
            single = np.mean(np.array(rows["single"]), axis=0)
            fixed = np.mean(np.array(rows["fixed"]), axis=0)
            for name in ("across", "across-pack"):
                mine = np.mean(np.array(rows[name]), axis=0)
                worst = max(x[3] for x in rows[name])
                verdicts.append(
                    f"{rig}, {name}: {mine[3]:.3f} % (worst seed {worst:.3f} %) at "
                    f"{100 * (1 - BELOW):.0f} % of V0 vs single {single[3]:.3f} %: "
                    f"{'meets' if worst <= 0.5 and mine[3] < single[3] else 'MISSES'} "
                    f"<= 0.5 % and better than single; time {100 * mine[0] / fixed[0]:.0f} % "
                    f"and energy {100 * mine[1] / fixed[1]:.0f} % of the fixed two-pack plan"
                )
    print()
    for v in verdicts:
        print(v)
    print(f"({time.perf_counter() - started:.0f} s wall)")


def measured_voltages_of(tmap: ThrustMap) -> list[tuple[float, float]]:
    """The voltage ranges the map says it was measured at (its ``selection``)."""
    got = tmap.selection.get("measured_voltages_v")
    groups = got if isinstance(got, list) else measured_voltages([])
    return [(float(g["lo_v"]), float(g["hi_v"])) for g in groups]


if __name__ == "__main__":
    main()
