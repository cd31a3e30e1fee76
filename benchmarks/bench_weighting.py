"""How the motor map weighs its points (issue 44 item 14): held out by file, each file weighed
by the command range it covers (ours) beside the cells pooled over every file (before: a slow
ramp's samples in one file shrank another file's plateaus to one sample's worth each).

    python benchmarks/bench_weighting.py [--data ../shared/data] [--demo thrustmap-demo]

Prints, per set, the mean |e_Th| over EVERY held-out point (each file held out in turn, the
map fitted on the others) and per held-out file. ``--demo`` adds the demo's SR and MR folders
(run ``thrustmap demo`` first).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from thrustmap.fitting.fit.coefficients import fit_coefficients, pool
from thrustmap.fitting.loaders.load import load_datasets
from thrustmap.fitting.models import MODELS
from thrustmap.fitting.selection.options import Selection


def held_out(files: list[Path], by_file: bool) -> tuple[float, int, list[str]]:
    """Mean |e_Th| % over every held-out point, their count, and one cell per held-out file."""
    data = pool(load_datasets([str(f) for f in files]), Selection())
    m = MODELS["motor"]
    errs, cells = [], []
    for i, pts in enumerate(data.points):
        train, test = data.file_index != i, data.file_index == i
        t, b, th = data.take(train)
        groups = data.file_index[train] if by_file else None
        coef = fit_coefficients(m, t, b, th, "l2", groups=groups)
        tt, bt, tht = data.take(test)
        e = np.abs(m.evaluate(coef, tt, bt) - tht)
        errs.append(e)
        cells.append(f"{Path(pts.source).name} {float(np.mean(e)):.3f} (n={len(e)})")
    allerr = np.concatenate(errs)
    return float(np.mean(allerr)), len(allerr), cells


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--data", type=Path, default=Path(__file__).parents[2] / "shared" / "data")
    ap.add_argument("--demo", type=Path, help="a thrustmap demo output folder")
    args = ap.parse_args()
    x = args.data / "xnova-thrust-stand"
    sets = {
        "xNova SR (ramp, steps, steps-up)": sorted((x / "single_rotor").glob("xNova-SR-*.csv")),
        "xNova MR (ramp, steps)": sorted((x / "multirotor").glob("xNova-MR-*.csv")),
        "xNova SR steps + steps-up": [
            x / "single_rotor" / "xNova-SR-steps.csv",
            x / "single_rotor" / "xNova-SR-steps-up.csv",
        ],
    }
    if args.demo is not None:
        sets["demo SR"] = sorted((args.demo / "sr").glob("*.csv"))
        sets["demo MR"] = sorted((args.demo / "mr").glob("*.csv"))
    print("motor map, held out by file: mean |e_Th| % over every held-out point")
    for name, files in sets.items():
        if len(files) < 2 or not all(f.exists() for f in files):
            print(f"{name}: data not found")
            continue
        ours, n, cells = held_out(files, by_file=True)
        base, _, base_cells = held_out(files, by_file=False)
        print(f"{name}: each file by its range {ours:.3f} % | cells pooled (before) {base:.3f} %"
              f" (n={n})")  # fmt: skip
        print(f"    by file, ours:   {'; '.join(cells)}")
        print(f"    by file, before: {'; '.join(base_cells)}")


if __name__ == "__main__":
    main()
