"""Time `thrustmap report` on the xNova single-rotor stand files, against the 5 s budget.

Fits the four xNova SR files (as `thrustmap fit` does), then times the report end to end as the
command runs it — load the map and the files, select, validate every model three ways, export,
draw the figures, write the HTML — in wall and CPU seconds, plus the CLI's own start-up.
Run: python benchmarks/bench_report.py [FOLDER-WITH-xNova-SR-FILES] [REPEATS]
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

BUDGET_S = 5.0
FILES = ("xNova-SR-ramp.csv", "xNova-SR-steps-up.csv", "xNova-SR-steps.csv", "xNova-TM-SR.csv")
DEFAULT = Path(__file__).resolve().parents[1].parent / "shared/data/xnova-thrust-stand/single_rotor"


def main() -> int:
    folder = Path(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT
    repeats = int(sys.argv[2]) if len(sys.argv) > 2 else 3
    files = [folder / f for f in FILES]
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        print(f"xNova SR files not found: {', '.join(missing)}")
        return 1
    from thrustmap.fitting.fit.fitmap import fit_map
    from thrustmap.fitting.loaders.load import load_datasets

    with tempfile.TemporaryDirectory() as tmp:
        map_path = Path(tmp) / "map.json"
        fit_map(load_datasets([str(f) for f in files])).map.save(map_path)
        samples = sum(len(d) for d in load_datasets([str(f) for f in files]))

        t0 = time.perf_counter()
        from thrustmap.report.data import build
        from thrustmap.report.html import write_report

        import_s = time.perf_counter() - t0
        walls, cpus, size = [], [], 0
        for k in range(repeats):
            w, c = time.perf_counter(), time.process_time()
            size = write_report(build(map_path), str(Path(tmp) / f"r{k}.html"))
            walls.append(time.perf_counter() - w)
            cpus.append(time.process_time() - c)
        import resource

        child0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        cli_w = time.perf_counter()
        subprocess.run(
            [sys.executable, "-m", "thrustmap", "report", str(map_path), "-o",
             str(Path(tmp) / "cli.html")],
            check=True, capture_output=True,
        )  # fmt: skip
        cli_s = time.perf_counter() - cli_w
        child1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        cli_cpu = (child1.ru_utime + child1.ru_stime) - (child0.ru_utime + child0.ru_stime)
    best = min(walls)
    print(f"xNova SR report: {len(files)} files, {samples} samples, HTML {size / 1e6:.2f} MB")
    print(f"{'':34}{'thrustmap':>12}{'budget':>10}")
    print(f"{'report, best of ' + str(repeats) + ' (wall s)':34}{best:>12.2f}{BUDGET_S:>10.1f}")
    print(f"{'report, median CPU s':34}{sorted(cpus)[len(cpus) // 2]:>12.2f}{BUDGET_S:>10.1f}")
    print(f"{'first import of matplotlib etc. (s)':34}{import_s:>12.2f}{'':>10}")
    print(f"{'`thrustmap report` command (wall s)':34}{cli_s:>12.2f}{BUDGET_S:>10.1f}")
    print(f"{'`thrustmap report` command (CPU s)':34}{cli_cpu:>12.2f}{BUDGET_S:>10.1f}")
    print("(wall times depend on machine load; CPU seconds are the process's own work)")
    return 0 if best < BUDGET_S else 2


if __name__ == "__main__":
    sys.exit(main())
