"""Quasi-static staircase benchmark: the Crazyflie system-id deck's sweep on the simulator.

For load cells converting every 25..104 ms (one to four updates per 100 ms stair, the
converter's clock free against the command's) and three seeds, the simulated deck's log
(``thrustmap.rig.sim.sysid``) is reduced to points two ways and fitted with the default model:

- quasi-static pairing (the default selection: up and down legs paired at equal command);
- baseline: the same selection with the pairing switched off (stairs judged as plateaus, as
  before: too short to settle, most are dropped or kept lagged).

Printed per case: the share of the thrust range kept and the map's mean / max |error| in %
throttle against the simulator's true map, over the thrust the sweep reached (at the voltage it
had there).

Run: python benchmarks/bench_quasi_static.py
"""

from __future__ import annotations

import logging
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from thrustmap.core.errors import ThrustmapError
from thrustmap.fitting.fit.fitmap import fit_map
from thrustmap.fitting.loaders.load import load_dataset
from thrustmap.fitting.selection.options import Selection
from thrustmap.fitting.selection.points import select
from thrustmap.rig.sim.physics import true_throttle_fraction
from thrustmap.rig.sim.presets import preset
from thrustmap.rig.sim.sysid import SYSID_BATTERY, simulate_staircase, write_csv

PARAMS = replace(preset("crazyflie-2.1"), **SYSID_BATTERY)  # type: ignore[arg-type]
BASELINE = Selection(quasi_static_updates=0.0, quasi_static_lags=0.0)


def score(path: Path, sel: Selection, grid_t: np.ndarray, grid_b: np.ndarray) -> str:
    ds = load_dataset(path)
    try:
        pts = select(ds, sel)
        tmap = fit_map([ds], selection=sel).map
    except ThrustmapError:
        return f"{'no map (too few points kept)':>34}"
    top = float(np.max(ds.thrust_n))
    kept = (float(pts.thrust_n.max()) - max(float(pts.thrust_n.min()), 0.0)) / top * 100.0
    truth = true_throttle_fraction(PARAMS, 4, grid_t, grid_b) * 100.0
    err = np.abs(tmap.throttle_pct(grid_t, grid_b, corrected=False) - truth)
    return f"{len(pts):4d} pts {kept:5.1f} % {np.nanmean(err):6.2f} {np.nanmax(err):6.2f}"


def main() -> None:
    logging.disable(logging.WARNING)
    print(  # noqa: T201
        f"{'update':>8} {'seed':>4} | {'quasi-static pairing':^34} | {'baseline (plateaus)':^34}\n"
        f"{'':>13} | {'points, range kept, mean/max err %':>34} | {'(same columns)':>34}"
    )
    with tempfile.TemporaryDirectory() as tmp:
        for update_s in (0.025, 0.05, 0.096, 0.1, 0.104):
            for seed in (1, 2, 3):
                log = simulate_staircase(seed=seed, cell_update_s=update_s)
                path = write_csv(log, Path(tmp) / "cf.csv")
                # the truth over what the rotor really did: true steady thrust at each stair's
                # command and the voltage measured there, from 10 % of the top thrust up
                per_rotor = log.true_total_n / 4.0
                ok = per_rotor > 0.1 * per_rotor.max()
                grid_t, grid_b = per_rotor[ok], log.vbat_v[ok]
                ours = score(path, Selection(), grid_t, grid_b)
                base = score(path, BASELINE, grid_t, grid_b)
                print(f"{update_s * 1000:6.0f}ms {seed:4d} | {ours:>34} | {base:>34}")  # noqa: T201


if __name__ == "__main__":
    main()
