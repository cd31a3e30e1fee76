"""How long `thrustmap demo` takes, run again and again in the same folder (as a newcomer does).

Target (issue 35): at most 6 s, median of 3, on a quiet machine. It was 5.5 s before the demo
wrote an HTML report of each map, then 8-11 s. Now the two strategies (SR, MR), each with its
report, run in two worker processes. Printed beside it, the baseline: the same demo in one
process, one strategy after the other (as before), and where its CPU time goes.

Each run replaces the previous run's output in place (the demo's own files only), so the three
runs also check that the demo is re-runnable. Wall times depend on the machine's load: the CPU
time of the demo and its report worker is printed too; run it on an idle machine for the figure.

    python benchmarks/bench_demo.py [--runs 3]
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BASELINE = """
import sys
from pathlib import Path
from thrustmap.demo import run_demo
run_demo(Path(sys.argv[1]), reports=True, parallel=False)
"""

PHASES = """
import sys, time
from pathlib import Path
t0 = time.process_time()
from thrustmap.demo import run_demo, write_reports
t1 = time.process_time()
results = run_demo(Path(sys.argv[1]), parallel=False)
t2 = time.process_time()
write_reports(results)
t3 = time.process_time()
print(f"{t1 - t0:.2f} {t2 - t1:.2f} {t3 - t2:.2f}")
"""


def _timed(argv: list[str]) -> tuple[float, float]:
    """Wall and CPU seconds (the process and the children it waited for)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(argv, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    py = sys.executable
    with tempfile.TemporaryDirectory() as tmp:
        ours_dir, base_dir = Path(tmp) / "thrustmap-demo", Path(tmp) / "baseline"
        ours, base = [], []
        for _ in range(args.runs):  # interleaved, so a change in the machine's load hits both
            ours.append(_timed([py, "-m", "thrustmap", "demo", "-q", "-o", str(ours_dir)]))
            base.append(_timed([py, "-c", BASELINE, str(base_dir)]))  # replaces its own run
        phases = subprocess.run(
            [py, "-c", PHASES, str(Path(tmp) / "phases")],
            check=True, capture_output=True, text=True,
        ).stdout.split()  # fmt: skip
    load = os.getloadavg()[0]
    print(f"thrustmap demo, {args.runs} runs in one folder (load average {load:.1f}, "
          f"{os.cpu_count()} cores)")  # fmt: skip
    print(f"{'':34} {'wall median':>12} {'CPU median':>11}")
    for name, rows in (("thrustmap demo (SR, MR in parallel)", ours),
                       ("baseline: SR then MR, one process", base)):  # fmt: skip
        wall = statistics.median(w for w, _ in rows)
        cpu = statistics.median(c for _, c in rows)
        print(f"{name:34} {wall:10.2f} s {cpu:9.2f} s")
    print(f"CPU by phase (baseline): import {phases[0]} s, campaigns and fits {phases[1]} s, "
          f"two reports {phases[2]} s")  # fmt: skip
    print("target: <= 6 s wall, median of 3, on a quiet machine (5.5 s before the reports)")


if __name__ == "__main__":
    main()
