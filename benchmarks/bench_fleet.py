"""Fleet throughput: the plain serial loop against local workers (forked, and Dask's).

A synthetic fleet from the flight simulator (tests/support): four airframes (PX4 ULog of both
topic generations, ArduPilot DataFlash of Copter 4 and Copter ≤ 3.3), each log on its own slice
of a 6S battery, plus corrupt files. The same fleet is extracted into fresh output folders
(nothing reused): in this process (``fleet extract --workers 0``), on 2 worker processes forked
from this one (``--workers 2``, thrustmap.fleet.local), on a local Dask cluster of 1 and of 2
workers (what ``--dashboard`` runs, and what ``--workers`` ran before), and on a bare
ProcessPoolExecutor of 2 (the control). Start-up is timed apart from the run. Then a re-run with
nothing new, and the projection for 100,000 logs on 32 workers from the measured per-log cost
(docs/fleet.md explains it).

    python benchmarks/bench_fleet.py [--logs 160] [--seconds 60] [--rate-hz 50]
    python benchmarks/bench_fleet.py --whole 3 [--logs 146 --seconds 24 --rate-hz 12.5]

Baseline: the serial loop. Target: 2 workers ≥ 1.7× its throughput on 2 cores.

``--whole N``: the command as a user runs it, interpreter start, imports, workers and shutdown
included: ``thrustmap fleet extract --workers 1`` against ``--workers 2``, each into a fresh
folder, the two taking turns N times, small DataFlash logs of both Copter generations by
default; the median time of each and its ratio. ``--workers 1`` is the command plus ONE worker
process doing logs (the command itself only finds, plans, collects and writes the table);
``--workers 2`` the command plus two. Issue 34's target: 2 workers ≥ 1.7× 1 worker on 100+
small logs, three runs in a row on a quiet machine (the load average is printed before each
run, and the CPU seconds of each command with its workers). It also times the same command on
a fleet of one log: the fixed cost S that no number of workers shortens, from which the best
ratio two workers can reach on this fleet, (S + W) / (S + W / 2), is printed beside the
measured one.
"""

from __future__ import annotations

import argparse
import os
import statistics
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
    import thrustmap.fitting.mapfile  # noqa: F401
    import thrustmap.flightlogs.dataflash  # noqa: F401
    import thrustmap.flightlogs.ulog  # noqa: F401


def _warm(_: int) -> None:
    warm_up()


def _cpu(procs: list[object]) -> float:
    """User + system CPU seconds of these processes (every thread)."""
    total = 0.0
    for p in procs:
        t = p.cpu_times()  # type: ignore[attr-defined]
        total += t.user + t.system
    return total


def _busy_cpu_s() -> float:
    """CPU seconds the whole machine has spent busy since boot (Linux; 0 elsewhere)."""
    try:
        with open("/proc/stat") as f:
            v = [int(x) for x in f.readline().split()[1:]]
    except OSError:
        return 0.0
    idle = v[3] + (v[4] if len(v) > 4 else 0)
    return (sum(v[:8]) - idle) / os.sysconf("SC_CLK_TCK")


def whole_process(runs: int, logs: int, seconds: float, rate_hz: float) -> None:
    """``fleet extract`` as a command, 1 worker against 2, taking turns ``runs`` times."""
    import resource
    import shutil
    import subprocess

    dataflash = tuple(a for a in AIRFRAMES if a.writer.startswith("dataflash"))
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        fleet = make_fleet(root, max(1, -(-logs // len(dataflash))), duration_s=seconds,
                           rate_hz=rate_hz, airframes=dataflash, corrupt=False, no_mass=0)  # fmt: skip
        n = len(fleet.good)
        size = sum(p.stat().st_size for p in fleet.good)
        print(f"fleet: {n} DataFlash logs, {size / 1e6:.1f} MB, {seconds:g} s at {rate_hz:g} Hz "
              f"each; {os.cpu_count()} cores")  # fmt: skip
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get(
            "PYTHONPATH", "")]))  # fmt: skip
        one_log = root / "one-log"
        one_log.mkdir()
        shutil.copy(sorted(fleet.good)[0], one_log)

        def command(folder: Path, out: Path, w: int) -> tuple[float, float, float]:
            """Wall and CPU seconds (the command and its workers) of one run, and the CPU
            seconds other processes of the machine used meanwhile (the load it ran under)."""
            ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            busy0 = _busy_cpu_s()
            t0 = time.perf_counter()
            subprocess.run(
                [sys.executable, "-m", "thrustmap", "fleet", "extract", str(folder),
                 "-o", str(out), "--masses", str(fleet.masses_csv), "--map",
                 str(fleet.stand_map), "--workers", str(w), "--quiet"],
                env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            )  # fmt: skip
            took = time.perf_counter() - t0
            busy1 = _busy_cpu_s()
            ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            shutil.rmtree(out)
            cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
            return took, cpu, max(0.0, busy1 - busy0 - cpu)

        times: dict[int, list[float]] = {1: [], 2: []}
        cpus: dict[int, list[float]] = {1: [], 2: []}
        fixed: list[float] = []
        for k in range(runs):
            for w in (1, 2):
                load = os.getloadavg()[0]
                took, cpu, others = command(fleet.folder, root / f"out-{w}-{k}", w)
                times[w].append(took)
                cpus[w].append(cpu)
                print(f"run {k + 1}: {w} worker(s) {took:6.2f} s, CPU {cpu:6.2f} s in all its "
                      f"processes  (load average before {load:.1f}; other processes used "
                      f"{others:.2f} s of CPU meanwhile)")  # fmt: skip
            fixed.append(command(one_log, root / f"out-one-{k}", 1)[0])
        one, two = statistics.median(times[1]), statistics.median(times[2])
        s_fixed = statistics.median(fixed)
        work = max(one - s_fixed, 0.0)
        print(f"fixed cost S (the same command on a fleet of one log, median): {s_fixed:.2f} s; "
              f"log work W = {work:.2f} s; the best 2 workers can do against 1 on this fleet: "
              f"(S + W) / (S + W/2) = {(s_fixed + work) / (s_fixed + work / 2):.2f}×")  # fmt: skip
        ratios = [a / b for a, b in zip(times[1], times[2], strict=True)]
        print(f"median: 1 worker {one:.2f} s ({n / one:.1f} logs/s), 2 workers {two:.2f} s "
              f"({n / two:.1f} logs/s): 2 workers {one / two:.2f}× 1 worker (baseline); each "
              f"turn {', '.join(f'{r:.2f}×' for r in ratios)}")  # fmt: skip
        print(f"CPU of the whole command (median): 1 worker {statistics.median(cpus[1]):.2f} s, "
              f"2 workers {statistics.median(cpus[2]):.2f} s: what a second core must absorb; "
              "unlike the wall time it hardly moves with other jobs' load")  # fmt: skip
        met = sum(r >= 1.7 for r in ratios)
        print(f"target ≥ 1.7× in every turn: {met} of {len(ratios)} turns "
              f"({'met' if met == len(ratios) else 'NOT met'}); load average now "
              f"{os.getloadavg()[0]:.1f} (a loaded machine understates the second worker)")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", type=int, default=160, help="good logs (split over 4 airframes)")
    ap.add_argument("--seconds", type=float, default=60.0, help="flight time per log")
    ap.add_argument("--rate-hz", type=float, default=50.0, help="log rate")
    ap.add_argument("--repeat", type=int, default=3, help="runs per mode; the best is shown")
    ap.add_argument("--whole", type=int, metavar="N",
                    help="time the whole command, 1 worker against 2, N turns (see above)")  # fmt: skip
    a = ap.parse_args()
    if a.whole:
        argv = sys.argv[1:]
        whole_process(
            a.whole,
            a.logs if "--logs" in argv else 146,
            a.seconds if "--seconds" in argv else 24.0,
            a.rate_hz if "--rate-hz" in argv else 12.5,
        )
        return
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

        # Every mode is ready before the clock starts (clusters up, pool warm), and the modes
        # take turns within each repeat, so a change in the machine's load hits them alike.
        from concurrent.futures import ProcessPoolExecutor

        from thrustmap.fleet.discover import discover
        from thrustmap.fleet.task import process_log

        clusters: dict[int, tuple[object, object]] = {}
        startup: dict[int | str, float] = {}
        for workers in (1, 2):
            t0 = time.perf_counter()
            clusters[workers] = run.start_local_cluster(run.local_cluster_spec(workers, None))
            clusters[workers][1].run(warm_up)  # type: ignore[attr-defined]
            startup[workers] = time.perf_counter() - t0
        pool = ProcessPoolExecutor(2)
        list(pool.map(_warm, range(2)))
        from thrustmap.fleet import local

        t0 = time.perf_counter()
        forked = local.ForkPool(local.LocalSpec(2, 4 << 30))
        forked.start()
        startup["fork"] = time.perf_counter() - t0
        best: dict[str, float] = {}
        in_task: dict[str, float] = {}  # mean seconds inside process_log per log, best run
        # CPU seconds per log of this process (driver, client, scheduler, nannies) and of the
        # worker processes, every run: unlike wall-clock rates these hardly move with the load
        import psutil

        me = psutil.Process()
        procs: dict[str, list[psutil.Process]] = {"serial": [], "pool": []}
        procs["pool"] = [psutil.Process(pid) for pid in pool._processes]
        procs["fork"] = [psutil.Process(pid) for pid in forked.pids()]
        for workers, (_, client) in clusters.items():
            pids = client.run(os.getpid).values()  # type: ignore[attr-defined]
            procs[str(workers)] = [psutil.Process(pid) for pid in pids]
        cpu_main: dict[str, list[float]] = {}
        cpu_workers: dict[str, list[float]] = {}
        try:
            for k in range(a.repeat):
                for mode in ("serial", "1", "2", "fork", "pool"):
                    cfg = config_for(root, root / f"out-{mode}-{k}")
                    main0, workers0 = _cpu([me]), _cpu(procs[mode])
                    t0 = time.perf_counter()
                    if mode == "pool":
                        (cfg.out_dir / "df").mkdir(parents=True)
                        tasks, _ = run.plan(discover(sources), cfg, {})
                        t0 = time.perf_counter()
                        outcomes = list(pool.map(process_log, tasks))
                        took, spent = time.perf_counter() - t0, None
                    else:
                        connect = None
                        if mode not in ("serial", "fork"):
                            w = int(mode)
                            connect = lambda c=clusters[w][1], w=w: (c, 2 * w)  # noqa: E731
                        on = forked.run if mode == "fork" else None
                        r = run.fleet_extract(sources, cfg, connect=connect, local=on)
                        took = time.perf_counter() - t0
                        assert r.reused == 0 and len(r.outcomes) == n
                        outcomes = []
                        spent = sum(o.seconds for o in r.outcomes) / n
                    cpu_main.setdefault(mode, []).append((_cpu([me]) - main0) / n)
                    cpu_workers.setdefault(mode, []).append((_cpu(procs[mode]) - workers0) / n)
                    if took < best.get(mode, float("inf")):
                        best[mode] = took
                        if spent is not None:
                            in_task[mode] = spent
                    del outcomes
            # what a 2-worker cluster costs while it has nothing to do (heartbeats, ticks,
            # memory polls): CPU taken from the logs while they run
            _, client = clusters[2]
            main0, workers0, t0 = _cpu([me]), _cpu(procs["2"]), time.perf_counter()
            time.sleep(3.0)
            idle_s = time.perf_counter() - t0
            idle_main, idle_workers = _cpu([me]) - main0, _cpu(procs["2"]) - workers0
        finally:
            forked.close()
            pool.shutdown()
            for cluster, client in clusters.values():
                client.close()  # type: ignore[attr-defined]
                cluster.close()  # type: ignore[attr-defined]
        results = {mode: n / t for mode, t in best.items()}
        serial_s = best["serial"]
        per_log_s = serial_s / n
        print(f"{'serial loop (baseline)':24s} {results['serial']:7.1f} logs/s   "
              f"({per_log_s * 1e3:.0f} ms per log, {in_task['serial'] * 1e3:.0f} ms of it "
              "inside the log's task)")  # fmt: skip
        for workers in (1, 2):
            m = str(workers)
            idle = (best[m] * workers - in_task[m] * n) / n
            print(f"{f'{workers} Dask worker(s)':24s} {results[m]:7.1f} logs/s   "
                  f"{results[m] / results['serial']:.2f}× serial (cluster start-up "
                  f"{startup[workers]:.1f} s, not included); in-task {in_task[m] * 1e3:.0f} ms "
                  f"per log, workers idle {idle * 1e3:.1f} ms per log (scheduling)")  # fmt: skip
        print(f"{'2 forked workers':24s} {results['fork']:7.1f} logs/s   "
              f"{results['fork'] / results['serial']:.2f}× serial (--workers 2: start-up "
              f"{startup['fork'] * 1e3:.0f} ms, not included); in-task "
              f"{in_task['fork'] * 1e3:.0f} ms per log")  # fmt: skip
        print(f"{'2 plain processes':24s} {results['pool']:7.1f} logs/s   "
              f"{results['pool'] / results['serial']:.2f}× serial (a ProcessPoolExecutor, no "
              "Dask: what this machine gives two processes right now)")  # fmt: skip

        print("CPU per log, median of the runs (ms; the driver's process holds the client, the "
              "scheduler and the nannies):")  # fmt: skip
        for mode, label in (("serial", "serial loop"), ("1", "1 Dask worker"),
                            ("2", "2 Dask workers"), ("fork", "2 forked workers"),
                            ("pool", "2 plain processes")):  # fmt: skip
            m, w = statistics.median(cpu_main[mode]), statistics.median(cpu_workers[mode])
            print(f"  {label:22s} this process {m * 1e3:5.2f}   workers {w * 1e3:5.2f}   "
                  f"total {(m + w) * 1e3:5.2f}")  # fmt: skip
        print(
            f"idle 2-worker cluster: this process {idle_main / idle_s * 1e3:.1f} ms/s, "
            f"workers {idle_workers / idle_s * 1e3:.1f} ms/s together (of 2000 ms/s)"
        )
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
        target = results["fork"] / results["serial"]
        print(f"target 2 workers (--workers 2, forked) ≥ 1.7× serial: {target:.2f}× "
              f"({'met' if target >= 1.7 else 'NOT met'})")  # fmt: skip


if __name__ == "__main__":
    main()
