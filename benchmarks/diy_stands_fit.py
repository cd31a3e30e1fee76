"""The DIY stands' simulators: a sweep on each (the MQTB's own program through ``stand run``),
fitted, against the simulator's truth (the xnova-2207-6s plant), beside the 1 % target.

Run: python benchmarks/diy_stands_fit.py   (simulated clock: a few seconds)

einsz's throttle is the firmware's percent label, DShot ``map(pct, 1, 100, 1, 2000)``: its truth
is converted the same way; the MQTB's is µs of 1000..2000, in percent of that range.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np
from click.testing import CliRunner

from thrustmap.cli import cli
from thrustmap.fitting.fit.fitmap import fit_map
from thrustmap.fitting.loaders.load import load_dataset
from thrustmap.fitting.selection.options import Selection
from thrustmap.fitting.selection.points import select
from thrustmap.rig.sim.physics import true_throttle_fraction
from thrustmap.rig.sim.presets import preset

RUNS = {
    "einsz-whoop": ["sweep", "steps", "--from", "10", "--to", "60", "--step", "10", "--dwell", "2"],
    "avenhaus-thrust-stand": [
        "sweep",
        "steps",
        "--from",
        "10",
        "--to",
        "60",
        "--step",
        "10",
        "--dwell",
        "3",
    ],  # fmt: skip
    "mqtb-teststand": ["stand", "run"],
    "einsz-whoop SWEEP": ["stand", "run"],  # the firmware's own program
}


def run(name: str, out: Path) -> None:
    from thrustmap.rig.sim.peers import reset_benches

    reset_benches()  # each run on a fresh simulated bench (its clock starts at 0)
    args = RUNS[name]
    name = name.split()[0]
    url = f"sim://line-stand?preset={name}"
    if args[0] == "sweep":
        argv = [*args[:2], "--stand", url, *args[2:], "--yes", "-q", "-o", str(out)]
    else:
        argv = [*args, url, "--line-preset", name, "--yes", "-o", str(out)]
    result = CliRunner().invoke(cli, argv)
    if result.exit_code != 0:
        sys.exit(f"{name}: {result.output}")


def error_pct(name: str, csv: Path) -> tuple[float, float, int]:
    ds = load_dataset(csv)
    tmap = fit_map([ds]).map
    pts = select(ds, Selection())
    keep = pts.thrust_n > 0.05 * pts.thrust_n.max()
    t, b = pts.thrust_n[keep], pts.voltage_v[keep]
    fraction = true_throttle_fraction(preset("xnova-2207-6s"), 1, t, b)
    if name.startswith("einsz-whoop"):
        truth = 1.0 + (fraction * 2000.0 - 1.0) * 99.0 / 1999.0
    else:
        truth = fraction * 100.0
    err = np.abs(tmap.throttle_pct(t, b, corrected=False) - truth)
    return float(err.mean()), float(err.max()), int(keep.sum())


def main() -> None:
    print(f"{'preset':24s} {'points':>6s} {'mean |err| %':>13s} {'max |err| %':>12s}  target")
    with tempfile.TemporaryDirectory() as tmp:
        for name in RUNS:
            out = Path(tmp) / f"{name.replace(' ', '-')}.csv"
            run(name, out)
            mean, worst, n = error_pct(name, out)
            print(f"{name:24s} {n:6d} {mean:13.2f} {worst:12.2f}  mean < 1")


if __name__ == "__main__":
    main()
