"""Flight-log throughput in one run: thrustmap's readers beside the reference decoders.

| ours                               | baseline                                    |
|------------------------------------|---------------------------------------------|
| ULog reader (+ Df)                 | pyulog, the same topics (our reader wraps it) |
| DataFlash numpy decoder (+ Df)     | pymavlink DFReader reading the same messages |
| Betaflight blackbox decoder        | orangebox, only when it is installed (GPL-3, never a dependency) |

Files: the shared real logs (../shared/data/flightlogs, skipped when absent) and synthetic
flights written by the test-fixture generators in tests/support.

    .venv/bin/python benchmarks/bench_flightlogs.py [--minutes 5] [--repeat 3] [--profile]
    .venv/bin/python benchmarks/bench_flightlogs.py --whole-process [--repeat 5] [LOG ...]

``--profile`` adds a cProfile of the blackbox decoder (where its time goes).

``--whole-process`` measures what a user waits for: a fresh interpreter running
``thrustmap flightlog extract LOG -o df.csv`` beside a fresh interpreter that only loads the same
log with pyulog (ULog) or pymavlink's DFReader (DataFlash), and the blackbox MB/s. Each command
runs ``--repeat`` times, interleaved, after one warm-up (bytecode caches written, files in the
page cache); the median and the best time of each are printed, with the load average. Targets
(issue 34): ULog → Df ≤ 1.1× the pyulog load (median of 5 alternating runs) on a 3–4 MB log;
Betaflight blackbox: see bench_blackbox.py. On a shared, loaded machine the times scatter:
compare the ratio, not the seconds. More logs: ``--whole-process FILE ...``.
"""

from __future__ import annotations

import argparse
import os
import resource  # children's CPU time to the microsecond (os.times: 10 ms ticks)
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))  # the fixture generators live in tests/support

import numpy as np  # noqa: E402
from support import simulate_flight as simulate  # noqa: E402

from thrustmap.fitting.df.extraction import extract  # noqa: E402
from thrustmap.fitting.df_options import DfOptions  # noqa: E402
from thrustmap.flightlogs import blackbox, dataflash, ulog  # noqa: E402
from thrustmap.flightlogs.blackbox_decode import decode_file, decode_log_reference  # noqa: E402
from thrustmap.flightlogs.blackbox_format import split_logs  # noqa: E402

SHARED = ROOT.parent / "shared/data/flightlogs"
DF_MESSAGES = ["IMU", "BAT", "CURR", "RCOU", "CTUN", "ATT", "EV", "PARM", "MSG"]


def best_of(fn: Callable[[], object], repeat: int) -> float:
    times = []
    for _ in range(max(repeat, 1)):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def row(label: str, mb: float, t: float, base: float | None = None, how: str = "") -> None:
    rel = ""
    if base is not None:
        rel = f"  {base / t:6.1f}x the baseline speed" if how == "x" else f"  {t / base:.2f}x time"
    print(f"  {label:34s} {t:8.3f} s {mb / t:8.1f} MB/s{rel}")


def extract_quiet(flights: list[object]) -> object:
    try:
        return extract(flights, DfOptions(mass_kg=1.0))  # type: ignore[arg-type]
    except Exception as exc:  # a log without a Df (no voltage): the timing is still the reader's
        return exc


# -- ULog -----------------------------------------------------------------------------------------


def bench_ulog(path: Path, label: str, repeat: int) -> None:
    from pyulog import ULog

    mb = path.stat().st_size / 1e6
    print(f"ULog, {label}: {path.name}, {mb:.2f} MB")
    t_py = best_of(lambda: ULog(str(path), message_name_filter_list=ulog.TOPICS), repeat)
    t_read = best_of(lambda: ulog.read(path), repeat)
    t_df = best_of(lambda: extract_quiet(ulog.read(path)), repeat)  # type: ignore[arg-type]
    row("pyulog, same topics (baseline)", mb, t_py)
    row("thrustmap reader", mb, t_read, t_py)
    row("thrustmap reader + Df", mb, t_df, t_py)


# -- DataFlash ------------------------------------------------------------------------------------


def pymavlink_arrays(path: Path) -> dict[str, np.ndarray]:
    from pymavlink import DFReader

    reader = DFReader.DFReader_binary(str(path))
    rows: dict[str, list[list[float]]] = {}
    while True:
        m = reader.recv_match(type=DF_MESSAGES)
        if m is None:
            break
        d = m.to_dict()
        rows.setdefault(m.get_type(), []).append(
            [float(v) for k, v in d.items() if k != "mavpackettype" and isinstance(v, (int, float))]
        )
    return {k: np.asarray(v) for k, v in rows.items()}


def bench_dataflash(path: Path, label: str, repeat: int) -> None:
    mb = path.stat().st_size / 1e6
    print(f"DataFlash, {label}: {path.name}, {mb:.2f} MB")
    t_base = best_of(lambda: pymavlink_arrays(path), 1)
    t_read = best_of(lambda: dataflash.read(path), repeat)
    t_df = best_of(lambda: extract_quiet(dataflash.read(path)), repeat)  # type: ignore[arg-type]
    row("pymavlink DFReader (baseline)", mb, t_base)
    row("thrustmap reader", mb, t_read, t_base, "x")
    row("thrustmap reader + Df", mb, t_df, t_base, "x")


# -- Betaflight blackbox --------------------------------------------------------------------------


def bench_blackbox(path: Path, label: str, repeat: int, profile: bool) -> None:
    data = path.read_bytes()
    mb = len(data) / 1e6
    frames = sum(len(lg.main) for lg in decode_file(data))
    print(f"Blackbox, {label}: {path.name}, {mb:.2f} MB, {frames} main frames")
    t_decode = best_of(lambda: decode_file(data), repeat)
    t_ref = best_of(
        lambda: [decode_log_reference(data[a:b]) for a, b in split_logs(data)], max(repeat // 2, 1)
    )
    t_read = best_of(lambda: blackbox.read(path), repeat)
    try:
        from orangebox import Parser  # type: ignore[import-not-found]
    except ImportError:
        Parser = None
    t_ob = None
    if Parser is not None:

        def orange() -> None:
            parser = Parser.load(str(path))
            for _ in parser.frames():
                pass

        t_ob = best_of(orange, 1)
        row("orangebox (baseline)", mb, t_ob)
    else:
        print("  orangebox (baseline)               not installed here: no baseline measured")
    row("thrustmap reference (per frame)", mb, t_ref, t_ob, "x")
    row("thrustmap decode_file (bulk numpy)", mb, t_decode, t_ob, "x")
    row("thrustmap blackbox.read (+ units)", mb, t_read, t_ob, "x")
    wall, cpu = blackbox_whole_process_cpu(path, repeat)
    print(f"  whole process, `thrustmap flightlog extract` (best of {repeat}): wall {wall:.3f} s "
          f"({mb / wall:.2f} MB/s), CPU user+sys {cpu:.3f} s ({mb / cpu:.2f} MB/s; on a loaded "
          "machine the CPU time is the steadier figure)")  # fmt: skip
    if profile:
        import cProfile
        import pstats

        prof = cProfile.Profile()
        prof.enable()
        decode_file(data)
        prof.disable()
        print("  where decode_file spends its time (cProfile, tottime):")
        stats = pstats.Stats(prof)
        stats.sort_stats("tottime").print_stats(8)


def blackbox_whole_process_cpu(path: Path, repeat: int) -> tuple[float, float]:
    """Best wall and best CPU (user + system) time of a fresh ``thrustmap flightlog extract``."""
    import subprocess

    walls, cpus = [], []
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "thrustmap", "flightlog", "extract", str(path),
               "--mass-kg", "1.0", "-o", str(Path(tmp) / "df.csv")]  # fmt: skip
        for k in range(max(repeat, 1) + 1):  # the first run writes the bytecode caches
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            t = time.perf_counter()
            subprocess.run(cmd, capture_output=True, env=_env(), check=True, timeout=600, cwd=tmp)
            wall = time.perf_counter() - t
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            if k:
                walls.append(wall)
                cpus.append(
                    after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
                )  # fmt: skip
    return min(walls), min(cpus)


# -- whole process ---------------------------------------------------------------------------------

PYULOG_LOAD = "import sys\nfrom pyulog import ULog\nULog(sys.argv[1])\n"
DFREADER_LOAD = (
    "import sys\nfrom pymavlink import DFReader\nr = DFReader.DFReader_binary(sys.argv[1])\n"
    "while r.recv_msg() is not None:\n    pass\n"
)
ORANGEBOX_LOAD = (
    "import sys\nfrom orangebox import Parser\np = Parser.load(sys.argv[1])\n"
    "for _ in p.frames():\n    pass\n"
)


def _env() -> dict[str, str]:
    import os

    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)  # as installed: compiled modules are cached
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def _timed(cmd: list[str]) -> tuple[float, float]:
    """Wall and CPU (user + system) seconds of one run of ``cmd``."""
    import subprocess

    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, env=_env(), check=False, timeout=600)
    dt = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if res.returncode not in (0,):
        last = (res.stderr.decode(errors="replace").strip().splitlines() or ["?"])[-1]
        raise RuntimeError(f"exited {res.returncode}: {last[:120]}")
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    return dt, cpu


def whole_process(path: Path, label: str, baseline: tuple[str, str] | None, repeat: int) -> None:
    mb = path.stat().st_size / 1e6
    with tempfile.TemporaryDirectory() as tmp:
        ours = [sys.executable, "-m", "thrustmap", "flightlog", "extract", str(path),
                "--mass-kg", "1.0", "-o", str(Path(tmp) / "df.csv")]  # fmt: skip
        cmds = {"thrustmap flightlog extract (→ Df CSV)": ours}
        if baseline is not None:
            cmds[baseline[0]] = [sys.executable, "-c", baseline[1], str(path)]
        runs: dict[str, list[tuple[float, float]]] = {}
        for name, cmd in cmds.items():
            try:
                _timed(cmd)  # warm-up
            except RuntimeError as exc:
                print(f"  {name}: not measured ({exc})")
                continue
            runs[name] = []
        for _ in range(max(repeat, 1)):  # alternating
            for name in runs:
                runs[name].append(_timed(cmds[name]))
    load = " ".join(f"{x:.1f}" for x in os.getloadavg())
    print(f"{label}: {path.name}, {mb:.2f} MB, whole process, {repeat} alternating runs "
          f"(load average {load} on {os.cpu_count()} CPUs)")  # fmt: skip
    base = runs.get(baseline[0]) if baseline else None
    for name, got in runs.items():
        wall = statistics.median(w for w, _ in got)
        cpu = statistics.median(c for _, c in got)
        print(f"  {name:42s} median wall {wall:6.3f} s ({mb / wall:5.2f} MB/s), "
              f"median CPU {cpu:6.3f} s")  # fmt: skip
        if base and name != baseline[0]:
            b_wall = statistics.median(w for w, _ in base)
            b_cpu = statistics.median(c for _, c in base)
            print(f"  {'':42s} {wall / b_wall:.2f}× the baseline's wall time, "
                  f"{cpu / b_cpu:.2f}× its CPU time (medians)")  # fmt: skip


def main_whole_process(repeat: int, shared: Path, extra: list[Path], kinds: str) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        logs: list[tuple[Path, str, tuple[str, str] | None]] = []
        for p in extra:
            logs.append((p, "given log", None))
        for rel, kind in (("px4/sitl_v1.15_sample_px4_events.ulg", "ulog"),
                          ("ardupilot/copter3.4_pxf_3s.bin", "bin"),
                          ("betaflight/bf4.2.8_4s.bbl", "bbl")):  # fmt: skip
            if (shared / rel).exists():
                logs.append((shared / rel, f"shared real log ({kind})", None))
            else:
                print(f"shared log not found at {shared / rel}; skipped (--shared DIR)")
        # a ULog as large as the one in issue 21 (3.8 MB): a simulated 200 Hz hover
        flight = simulate.simulate_hover(simulate.HoverSim(duration_s=150.0, rate_hz=200.0))
        synth = Path(tmp) / "synthetic_hover.ulg"
        simulate.write_ulog(flight, synth)
        logs.append((synth, "synthetic 150 s hover at 200 Hz", None))
        logs.append((ROOT / "fixtures/flightlogs/bb_hover_sim.bbl", "fixture", None))
        wanted = {"." + k.strip().lstrip(".") for k in kinds.split(",") if k.strip()}
        for path, label, _ in logs:
            if wanted and path.suffix not in wanted:
                continue
            if path.suffix == ".ulg":
                base: tuple[str, str] | None = ("pyulog load (baseline)", PYULOG_LOAD)
            elif path.suffix == ".bin":
                base = ("pymavlink DFReader, every message (baseline)", DFREADER_LOAD)
            else:
                base = ("orangebox, every frame (baseline)", ORANGEBOX_LOAD)
            whole_process(path, label, base, repeat)


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--minutes", type=float, default=5.0, help="synthetic flight length")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--profile", action="store_true", help="profile the blackbox decoder")
    ap.add_argument(
        "--whole-process", action="store_true", help="fresh interpreters, as a user runs them"
    )
    ap.add_argument("--shared", type=Path, default=SHARED, help="folder of the shared real logs")
    ap.add_argument(
        "logs", nargs="*", type=Path, help="more logs for --whole-process (.ulg, .bin, .bbl)"
    )
    ap.add_argument("--kinds", default="", help="--whole-process only these suffixes: ulg,bin,bbl")
    args = ap.parse_args()
    if args.whole_process:
        main_whole_process(args.repeat, args.shared, args.logs, args.kinds)
        return
    for name in ("sitl_v1.15_sample_px4_events.ulg", "fmuv3_v1.9_esc_status.ulg"):
        p = SHARED / "px4" / name
        if p.exists():
            bench_ulog(p, "shared real log", args.repeat)
        else:
            print(f"shared log not found at {p}; skipped")
    p = SHARED / "ardupilot/copter3.4_pxf_3s.bin"
    if p.exists():
        bench_dataflash(p, "shared real log (Copter 3.4)", args.repeat)
    else:
        print(f"shared log not found at {p}; skipped")
    p = SHARED / "betaflight/bf4.2.8_4s.bbl"
    if not p.exists():
        p = ROOT / "fixtures/flightlogs/bb_hover_sim.bbl"
    bench_blackbox(p, "real Betaflight 4.2.8" if "shared" in str(p) else "fixture", args.repeat,
                   args.profile)  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        flight = simulate.simulate_hover(
            simulate.HoverSim(duration_s=args.minutes * 60.0, rate_hz=200.0, seed=0)
        )
        synth = f"synthetic {args.minutes:g} min flight at 200 Hz"
        path = Path(tmp) / "synthetic.ulg"
        simulate.write_ulog(flight, path)
        bench_ulog(path, synth, args.repeat)
        path = Path(tmp) / "synthetic.bin"
        simulate.write_dataflash(flight, path)
        bench_dataflash(path, synth, args.repeat)


if __name__ == "__main__":
    main()
