"""Fleet throughput: logs per second for the plain serial loop, 1 and 2 local Dask workers.

A synthetic fleet from the flight simulator (tests/support): four airframes (PX4 ULog of both
topic generations, ArduPilot DataFlash of Copter 4 and Copter ≤ 3.3), each log on its own slice
of a 6S battery, plus corrupt files. The same fleet is extracted three times into fresh output
folders (nothing reused): in this process (``fleet extract --workers 0``), and on a local
cluster of 1 and of 2 worker processes. Cluster start-up is timed apart from the run (it is paid
once per command, not per log). Then a re-run with nothing new, and the projection for 100,000
logs on 32 workers from the measured per-log cost (docs/fleet.md explains it).

    python benchmarks/bench_fleet.py [--logs 160] [--seconds 60] [--rate-hz 50]

Baseline: the serial loop. Target: 2 workers ≥ 1.7× its throughput on 2 cores.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))  # the fixture generators live in tests/support
sys.path.insert(0, str(ROOT))

from support.fleet_gen import AIRFRAMES, make_fleet  # noqa: E402

from thrustmap.fleet import run  # noqa: E402


def config_for(root: Path, out: Path) -> run.FleetConfig:
    return run.FleetConfig(
        out_dir=out,
        df_options={"rotors": None},
        masses=run.read_masses(root / "masses.csv"),
        map_path=root / "stand-map.json",
    )


def warm_up() -> None:
    """Import what a log needs (numpy, pandas, the readers) before the clock starts."""
    import thrustmap.fitting.df  # noqa: F401
    import thrustmap.fitting.flightlogs.dataflash  # noqa: F401
    import thrustmap.fitting.flightlogs.ulog  # noqa: F401
    import thrustmap.fitting.mapfile  # noqa: F401


def _warm(_: int) -> None:
    warm_up()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", type=int, default=160, help="good logs (split over 4 airframes)")
    ap.add_argument("--seconds", type=float, default=60.0, help="flight time per log")
    ap.add_argument("--rate-hz", type=float, default=50.0, help="log rate")
    ap.add_argument("--repeat", type=int, default=2, help="runs per mode; the best is shown")
    a = ap.parse_args()
    print(f"load average before: {' '.join(f'{x:.1f}' for x in os.getloadavg())} "
          "(a loaded machine understates the workers' gain: rerun when it is idle)")  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        t0 = time.perf_counter()
        fleet = make_fleet(root, max(1, a.logs // len(AIRFRAMES)), duration_s=a.seconds,
                           rate_hz=a.rate_hz)  # fmt: skip
        n = len(fleet.good) + len(fleet.corrupt) + len(fleet.no_mass)
        size = sum(p.stat().st_size for p in fleet.folder.rglob("*") if p.is_file())
        print(f"fleet: {n} logs ({len(fleet.good)} good, {len(fleet.corrupt)} corrupt, "
              f"{len(fleet.no_mass)} without a mass), {size / 1e6:.1f} MB, "
              f"{a.seconds:g} s at {a.rate_hz:g} Hz each; generated in "
              f"{time.perf_counter() - t0:.1f} s; {os.cpu_count()} cores")  # fmt: skip
        sources = [fleet.folder]
        warm_up()

        results: dict[str, float] = {}
        in_task: dict[str, float] = {}  # mean seconds inside process_log per log
        serial_s = float("inf")
        for k in range(a.repeat):
            out = root / f"out-serial-{k}"
            t0 = time.perf_counter()
            r = run.fleet_extract(sources, config_for(root, out))
            took_k = time.perf_counter() - t0
            assert r.reused == 0 and len(r.outcomes) == n
            if took_k < serial_s:
                serial_s = took_k
                in_task["serial"] = sum(o.seconds for o in r.outcomes) / n
        results["serial"] = n / serial_s
        per_log_s = serial_s / n
        print(f"{'serial loop (baseline)':24s} {results['serial']:7.1f} logs/s   "
              f"({per_log_s * 1e3:.0f} ms per log, {in_task['serial'] * 1e3:.0f} ms of it "
              "inside the log's task)")  # fmt: skip

        for workers in (1, 2):
            spec = run.local_cluster_spec(workers, None)
            t0 = time.perf_counter()
            cluster, client = run.start_local_cluster(spec)
            client.run(warm_up)
            startup_s = time.perf_counter() - t0
            took = float("inf")
            try:
                for k in range(a.repeat):
                    out = root / f"out-{workers}-{k}"
                    t0 = time.perf_counter()
                    r = run.fleet_extract(
                        sources,
                        config_for(root, out),
                        connect=lambda c=client, w=workers: (c, 2 * w),
                    )
                    took_k = time.perf_counter() - t0
                    assert r.reused == 0 and len(r.outcomes) == n
                    if took_k < took:
                        took = took_k
                        in_task[str(workers)] = sum(o.seconds for o in r.outcomes) / n
            finally:
                client.close()
                cluster.close()
            results[str(workers)] = n / took
            idle = (took * workers - in_task[str(workers)] * n) / n
            print(f"{f'{workers} Dask worker(s)':24s} {n / took:7.1f} logs/s   "
                  f"{n / took / results['serial']:.2f}× serial (cluster start-up "
                  f"{startup_s:.1f} s, not included; with it {n / (took + startup_s):.1f} logs/s); "
                  f"in-task {in_task[str(workers)] * 1e3:.0f} ms per log, workers idle "
                  f"{idle * 1e3:.1f} ms per log (scheduling)")  # fmt: skip

        # the machine's own ceiling for two processes: a plain process pool, no Dask
        from concurrent.futures import ProcessPoolExecutor

        from thrustmap.fleet.discover import discover
        from thrustmap.fleet.task import process_log

        pool_s = float("inf")
        with ProcessPoolExecutor(2) as pool:
            list(pool.map(_warm, range(2)))
            for k in range(a.repeat):
                cfg = config_for(root, root / f"out-pool-{k}")
                (cfg.out_dir / "df").mkdir(parents=True)
                tasks, _ = run.plan(discover(sources), cfg, {})
                t0 = time.perf_counter()
                list(pool.map(process_log, tasks))
                pool_s = min(pool_s, time.perf_counter() - t0)
        print(f"{'2 plain processes':24s} {n / pool_s:7.1f} logs/s   "
              f"{n / pool_s / results['serial']:.2f}× serial (a ProcessPoolExecutor, no Dask: "
              "what this machine gives two processes right now)")  # fmt: skip

        t0 = time.perf_counter()
        r = run.fleet_extract(sources, config_for(root, root / "out-serial-0"))
        again_s = time.perf_counter() - t0
        print(f"re-run with nothing new: {again_s:.3f} s ({again_s / serial_s * 100:.1f} % of "
              f"the first serial run; {r.reused} of {n} skipped)")  # fmt: skip
        eff = results["2"] / (2 * results["1"])
        idle1 = (n / results["1"] - in_task["1"] * n) / n  # scheduling per log, 1 worker
        cost_s = in_task["serial"] + max(idle1, 0.0)  # a log on a worker with a core to itself
        proj = 100_000 * cost_s / 32
        print(f"measured 2-worker efficiency here {eff:.2f} (logs/s per worker vs 1 worker)")
        print(f"projection: 100,000 such logs on 32 workers (a core each) ≈ {proj / 60:.1f} min "
              f"= 100,000 × ({in_task['serial'] * 1e3:.0f} ms in the task + {idle1 * 1e3:.1f} ms "
              f"scheduling) / 32, plus start-up; the serial loop ≈ "
              f"{100_000 * per_log_s / 3600:.1f} h")  # fmt: skip
        print(f"load average after: {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
        grow = in_task["2"] / in_task["1"]
        if grow > 1.3:
            print(f"note: a log's in-task time grew {grow:.2f}× from 1 to 2 workers: the two "
                  "cores were shared with other work, so the 2-worker figure is CPU-bound, not "
                  "scheduling-bound")  # fmt: skip
        target = results["2"] / results["serial"]
        print(f"target 2 workers ≥ 1.7× serial: {target:.2f}× "
              f"({'met' if target >= 1.7 else 'NOT met'})")  # fmt: skip


if __name__ == "__main__":
    main()
