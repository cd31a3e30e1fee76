"""DIY line-stand presets (issue 43): a sweep on each preset's simulated stand, fitted and scored
against the simulator's truth, and the calibrations found on the real-firmware recordings.

    python benchmarks/bench_stand_presets.py

- tiny-thrust-stand: ``thrustmap stand run`` on ``sim://line-stand?preset=tiny-thrust-stand``
  (its own sweep, duty 0..190 of 255), the crazyflie-2.1 plant;
- victorhook-thruststand: ``thrustmap sweep steps`` 10..60 % step 10, dwell 2 s, the motor driven
  by a simulated Betaflight FC (the stand drives none), the xnova-2207-6s plant.

Each log is fitted with the defaults (``fit_map``) and scored as mean and max |map - truth| in %
throttle at its steady points above 5 % of its top thrust. Acceptance: within 1 % (mean).
The recordings' calibrations (``fixtures/stands/*/cal.json``) are printed beside the counts per
gram the harness set.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

RUNS = {
    "tiny-thrust-stand": (
        "crazyflie-2.1",
        ["stand", "run", "sim://line-stand?preset=tiny-thrust-stand&plant=crazyflie-2.1",
         "--line-preset", "tiny-thrust-stand", "--yes"],
    ),
    "victorhook-thruststand": (
        "xnova-2207-6s",
        ["sweep", "steps", "--stand", "sim://line-stand?preset=victorhook-thruststand",
         "--throttle", "sim://betaflight", "--to", "60", "--step", "10", "--dwell", "2",
         "--yes", "-q"],
    ),
}  # fmt: skip
SET_COUNTS_PER_GRAM = {"tiny-thrust-stand": -422.0, "victorhook-thruststand": -400.0}


def truth_error_pct(csv: Path, plant: str) -> tuple[float, float, int]:
    from thrustmap.fitting.fit import fit_map
    from thrustmap.fitting.loaders import load_dataset
    from thrustmap.fitting.selection import Selection, select
    from thrustmap.rig.sim.physics import true_throttle_fraction
    from thrustmap.rig.sim.presets import preset

    ds = load_dataset(csv)
    tmap = fit_map([ds]).map
    pts = select(ds, Selection())
    keep = pts.thrust_n > 0.05 * pts.thrust_n.max()
    t, b = pts.thrust_n[keep], pts.voltage_v[keep]
    truth = true_throttle_fraction(preset(plant), 1, t, b) * 100.0
    err = np.abs(tmap.throttle_pct(t, b, corrected=False) - truth)
    return float(err.mean()), float(err.max()), int(keep.sum())


def main() -> None:
    from thrustmap.core.physical import G0
    from thrustmap.rig.stand.line_calibration import load_line_calibration

    print(f"{'preset':<24} {'points':>6} {'mean %':>7} {'max %':>6}  (acceptance: mean < 1 %)")
    with tempfile.TemporaryDirectory() as tmp:
        for name, (plant, args) in RUNS.items():
            out = Path(tmp) / f"{name}.csv"
            r = subprocess.run(
                [sys.executable, "-m", "thrustmap", *args, "-o", str(out)],
                capture_output=True, text=True, cwd=ROOT,
            )  # fmt: skip
            if r.returncode != 0:
                print(f"{name:<24} failed: {r.stderr.strip()}")
                continue
            mean, worst, n = truth_error_pct(out, plant)
            print(f"{name:<24} {n:>6} {mean:>7.2f} {worst:>6.2f}")
    print(f"\n{'recording':<24} {'found counts/g':>15} {'set':>7}")
    for name, set_value in SET_COUNTS_PER_GRAM.items():
        cal = load_line_calibration(ROOT / "fixtures" / "stands" / name / "cal.json")
        print(f"{name:<24} {cal.counts_per_n * G0 / 1000.0:>15.2f} {set_value:>7.1f}")


if __name__ == "__main__":
    main()
