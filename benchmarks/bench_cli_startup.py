"""How fast the CLI answers `--help`: `thrustmap --help` and `thrustmap <cmd> --help`.

Target: under 0.3 s each. Baseline printed beside it: a bare Python start (the floor) and
importing the heavy libraries the commands use (numpy, pandas, scipy, pymavlink), which is what
every command paid before they were imported lazily.

    python benchmarks/bench_cli_startup.py [--runs 7]
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
import sys
import time

COMMANDS = [
    [],
    ["models"], ["fit"], ["compare"], ["evaluate"], ["predict"], ["inspect"],
    ["ports"], ["probe"], ["spin"], ["sweep"], ["demo"],
    ["flightlog"], ["flightlog", "extract"], ["gamma"], ["gamma", "fit"], ["export"],
    ["report"], ["plot"],
]  # fmt: skip


def _median_s(argv: list[str], runs: int) -> float:
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        subprocess.run(argv, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=7)
    args = parser.parse_args()
    exe = shutil.which("thrustmap")
    base = [exe] if exe else [sys.executable, "-m", "thrustmap"]
    floor = _median_s([sys.executable, "-c", "pass"], args.runs)
    heavy = _median_s(
        [sys.executable, "-c", "import numpy, pandas, scipy.optimize, pymavlink.mavutil"],
        args.runs,
    )
    print(f"baseline: bare python start {floor:.3f} s; importing numpy+pandas+scipy+pymavlink "
          f"{heavy:.3f} s (what each command paid before lazy imports)")  # fmt: skip
    worst = 0.0
    for cmd in COMMANDS:
        t = _median_s([*base, *cmd, "--help"], args.runs)
        worst = max(worst, t)
        label = " ".join(["thrustmap", *cmd, "--help"])
        print(f"{label:<36} {t:.3f} s  {'ok' if t < 0.3 else 'OVER 0.3 s'}")
    print(f"slowest: {worst:.3f} s (target < 0.3 s)")


if __name__ == "__main__":
    main()
