"""Wall time of the simulated SR and MR stand sweeps the demo runs (xNova preset).

Each sweep: steps from 10 % to 80 % throttle in 2.5 % increments, 3 s on the step and 3 s back
at 10 % (the paper's step experiments), about 3 minutes of simulated time, sampled at 50 Hz.
Baseline: the same sweeps with a fixed 1 ms substep everywhere (no settled-rotor substeps).
Target: both sweeps together in a few seconds of wall time.

Run: .venv/bin/python benchmarks/bench_sim.py
"""

from __future__ import annotations

import time

import numpy as np

from thrustmap.rig.sim.physics import make_plant

SAMPLE_HZ = 50.0


def sweep(rotors: int, **overrides: float) -> tuple[float, float, int]:
    plant = make_plant("xnova-2207-6s", rotors_on_esc=rotors, seed=1, **overrides)
    levels = np.arange(0.10, 0.8001, 0.025)
    schedule: list[tuple[float, float]] = []
    t = 1.0
    for level in levels:
        schedule += [(t, float(level)), (t + 3.0, 0.10)]
        t += 6.0
    end_s = t
    started = time.perf_counter()
    k, samples, nxt = 0, 0, 0
    while k / SAMPLE_HZ <= end_s:
        now = k / SAMPLE_HZ
        while nxt < len(schedule) and schedule[nxt][0] <= now + 1e-9:
            for m in range(rotors):
                plant.set_throttle(m, schedule[nxt][1], now)
            nxt += 1
        plant.state(now)
        samples += 1
        k += 1
    for m in range(rotors):
        plant.set_throttle(m, 0.0, plant.time_s)
    return time.perf_counter() - started, end_s, samples


def main() -> None:
    total = 0.0
    for rotors, label in ((1, "SR"), (4, "MR")):
        wall, sim_s, n = sweep(rotors)
        base, _, _ = sweep(rotors, settled_substep_s=0.001)
        total += wall
        print(
            f"{label} sweep: {sim_s:.0f} s simulated, {n} samples: {wall:.2f} s wall "
            f"({sim_s / wall:.0f}x real time); baseline fixed 1 ms substep: {base:.2f} s"
        )
    print(f"SR + MR: {total:.2f} s wall (target: a few seconds)")


if __name__ == "__main__":
    main()
