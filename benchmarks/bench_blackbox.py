"""Betaflight blackbox logs, whole process: ``thrustmap flightlog extract`` beside orangebox.

For every log file given (files or folders; by default the shared real logs in
../shared/data/flightlogs/betaflight, skipped when absent) this prints, in one run:

- what the file holds: logs (sessions), main / GPS (G) / GPS-home (H) / slow (S) frames, and
  which path decoded each log (``bulk``: all of it in bulk; ``bulk+ref``: a clean first stretch
  in bulk, the rest frame by frame; ``ref``: all frame by frame, the per-frame reference);
- the median wall time and the median CPU time (user + system) of a fresh interpreter running
  ``thrustmap flightlog extract FILE --mass-kg 1 -o df.csv``, as MB/s of the file;
- the same for orangebox (GPL-3, never a dependency of thrustmap) decoding every frame of every
  log of the file, when it is importable: ``--orangebox-path DIR`` (a folder holding the
  ``orangebox`` package, e.g. its wheel unpacked: orangebox 0.5.0 does not pip-install, its
  console-script entry points are invalid) or ``--orangebox-python PY`` (an interpreter that has
  it).

The two commands run ``--repeat`` times each, alternating, after one warm-up each (bytecode
caches written, files in the page cache). The load average is printed before and after: on a
shared machine the wall time scatters with the load; the CPU time is the steadier figure.
Target (issue 34): >= 5 MB/s whole process on every Betaflight log.

The floor: first, the same number of runs of a fresh interpreter that only imports what any
``thrustmap`` command needs (click, numpy with one BLAS thread, as the CLI sets it, logging).
No command can take less. A file smaller than 5 MB/s x that floor cannot reach 5 MB/s even if
its decoding, Df and CSV took no time: each file's line says ``met``, ``not met`` or ``below the
floor`` (judged on the median CPU time), and files under 300 kB (error-recovery test files) are
``tiny``: measured, never counted as met. The CPU time above the floor (decoding, Df, CSV and
thrustmap's own imports) is printed too: on a loaded machine both scale, their ratio less.

    python benchmarks/bench_blackbox.py [FILE_OR_DIR ...] [--repeat 5]
        [--orangebox-path DIR | --orangebox-python PY]
"""

from __future__ import annotations

import argparse
import os
import resource  # children's CPU time to the microsecond (os.times: 10 ms ticks)
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # describe() decodes with this tree's thrustmap, as the runs do
SHARED_BETAFLIGHT = ROOT.parent / "shared/data/flightlogs/betaflight"
SUFFIXES = (".bbl", ".bfl", ".txt")

TARGET_MB_S = 5.0
TINY_BYTES = 300_000
#: what every thrustmap command imports before its own work (the CLI sets one BLAS thread)
FLOOR = "import click, logging, numpy"

ORANGEBOX_ALL_LOGS = (
    "import sys\n"
    "from orangebox import Parser\n"
    "from orangebox.reader import Reader\n"
    "count = Reader(sys.argv[1]).log_count\n"
    "for i in range(1, count + 1):\n"
    "    for _ in Parser.load(sys.argv[1], i).frames():\n"
    "        pass\n"
)


def log_files(args: list[str]) -> list[Path]:
    found: list[Path] = []
    for a in args:
        p = Path(a).resolve()  # the commands run in a temporary folder
        if p.is_dir():
            found += sorted(q for q in p.rglob("*") if q.is_file() and q.suffix.lower() in SUFFIXES)
        elif p.is_file():
            found.append(p)
        else:
            print(f"{p}: not found; skipped")
    return found


def describe(path: Path) -> str:
    """Logs, frames and the decoding path of each log (in this process, not timed)."""
    import thrustmap.flightlogs.blackbox_format as blackbox_format
    from thrustmap.flightlogs import blackbox_decode as bd
    from thrustmap.flightlogs import blackbox_fast as bf
    from thrustmap.flightlogs.blackbox import used_field

    data = path.read_bytes()
    paths: dict[str, int] = {}
    totals = {"main": 0, "G": 0, "H": 0, "S": 0}
    ranges = blackbox_format.split_logs(data)
    for i, (a, b) in enumerate(ranges):
        got = bf.decode_log_bulk(data[a:b], i, a, keep_field=used_field)
        kind = (
            "bulk"
            if isinstance(got, blackbox_format.DecodedLog)
            else "ref"
            if got is None
            else "bulk+ref"
        )
        paths[kind] = paths.get(kind, 0) + 1
        dec = bd.decode_log(data[a:b], i, a, keep_field=used_field)
        totals["main"] += len(dec.main)
        for k in "GHS":
            totals[k] += dec.stats[k]
    how = ", ".join(f"{v} {k}" for k, v in sorted(paths.items()))
    frames = f"{totals['main']} main, {totals['G']} G, {totals['H']} H, {totals['S']} S frames"
    return f"{len(ranges)} log(s) ({how}); {frames}"


def env_with(pythonpath: str | None) -> dict[str, str]:
    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)  # as installed: compiled modules are cached
    parts = [p for p in (pythonpath, env.get("PYTHONPATH")) if p]
    env["PYTHONPATH"] = os.pathsep.join(parts)
    return env


#: the last stderr line of a command that refused its file (exit 2), by the command line
REFUSED: dict[str, str] = {}


def timed(
    cmd: list[str], env: dict[str, str], cwd: str, refusal_ok: bool = False
) -> tuple[float, float]:
    """Wall and CPU (user + system) seconds of one run of ``cmd``. With ``refusal_ok`` an exit 2
    (thrustmap refusing what it read: no accelerometer, an unphysical one) is timed too: the
    command decoded the whole file to reach that answer."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, env=env, cwd=cwd, check=False, timeout=600)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if res.returncode != 0:
        last = (res.stderr.decode(errors="replace").strip().splitlines() or ["?"])[-1]
        if not (refusal_ok and res.returncode == 2):
            raise RuntimeError(f"exited {res.returncode}: {last[:160]}")
        REFUSED[" ".join(cmd)] = last[:120]
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    return wall, cpu


def floor_cpu_s(repeat: int) -> float:
    """Median CPU seconds of a fresh interpreter importing only :data:`FLOOR`."""
    env = {**env_with(str(ROOT)), "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-c", FLOOR]
        timed(cmd, env, tmp)  # warm-up
        runs = [timed(cmd, env, tmp) for _ in range(max(repeat, 1))]
    wall = statistics.median(w for w, _ in runs)
    cpu = statistics.median(c for _, c in runs)
    print(f"floor ({FLOOR!r} in a fresh interpreter): median wall {wall:.3f} s, median CPU "
          f"{cpu:.3f} s: a file under {TARGET_MB_S * cpu:.2f} MB cannot reach "
          f"{TARGET_MB_S:g} MB/s CPU")  # fmt: skip
    return cpu


def verdict(size_bytes: int, cpu_s: float, floor_s: float) -> str:
    mb = size_bytes / 1e6
    if size_bytes < TINY_BYTES:
        return "tiny (under 300 kB): not counted"
    if mb / cpu_s >= TARGET_MB_S:
        return f"met (>= {TARGET_MB_S:g} MB/s CPU)"
    if mb < TARGET_MB_S * floor_s:
        return (f"below the floor: not met ({mb / floor_s:.2f} MB/s at most, with no decoding "
                "at all)")  # fmt: skip
    return "not met"


def bench_file(
    path: Path, repeat: int, ob_cmd: list[str] | None, ob_env: dict[str, str], floor_s: float
) -> None:
    mb = path.stat().st_size / 1e6
    try:
        what = describe(path)
    except Exception as exc:  # noqa: BLE001 - one odd file must not end the whole run
        what = f"not described ({type(exc).__name__}: {exc})"
    print(f"{path.name}: {mb:.2f} MB, {what}")
    with tempfile.TemporaryDirectory() as tmp:
        ours = [sys.executable, "-m", "thrustmap", "flightlog", "extract", str(path),
                "--mass-kg", "1.0", "-o", str(Path(tmp) / "df.csv")]  # fmt: skip
        cmds = {"thrustmap flightlog extract (→ Df CSV)": (ours, env_with(str(ROOT)))}
        if ob_cmd is not None:
            cmds["orangebox, every frame of every log"] = ([*ob_cmd, str(path)], ob_env)
        runs: dict[str, list[tuple[float, float]]] = {}
        for name, (cmd, env) in cmds.items():
            try:
                timed(cmd, env, tmp, refusal_ok=cmd is ours)  # warm-up
                runs[name] = []
            except (RuntimeError, subprocess.TimeoutExpired) as exc:
                print(f"  {name}: not measured ({exc})")
        for _ in range(max(repeat, 1)):
            for name in runs:
                cmd, env = cmds[name]
                runs[name].append(timed(cmd, env, tmp, refusal_ok=cmd is ours))
    for name, got in runs.items():
        wall = statistics.median(w for w, _ in got)
        cpu = statistics.median(c for _, c in got)
        print(f"  {name:40s} median wall {wall:6.3f} s {mb / wall:6.2f} MB/s   "
              f"median CPU {cpu:6.3f} s {mb / cpu:6.2f} MB/s")  # fmt: skip
        if name.startswith("thrustmap"):
            if " ".join(ours) in REFUSED:
                print(f"  {'':40s} timed to its refusal (exit 2): {REFUSED[' '.join(ours)]}")
            own = cpu - floor_s  # decoding, Df, CSV and thrustmap's own imports
            print(f"  {'':40s} {verdict(path.stat().st_size, cpu, floor_s)}; above the floor "
                  f"{own:.3f} s CPU" + (f" ({mb / own:.1f} MB/s)" if own > 0 else ""))  # fmt: skip
    if ob_cmd is None:
        print("  orangebox: not importable here (--orangebox-path DIR): no baseline measured")


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("logs", nargs="*", help="blackbox files or folders (default: the shared logs)")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--orangebox-path", help="folder holding the orangebox package")
    ap.add_argument("--orangebox-python", help="an interpreter that can import orangebox")
    args = ap.parse_args()
    targets = list(args.logs)
    if SHARED_BETAFLIGHT.is_dir():
        targets.insert(0, str(SHARED_BETAFLIGHT))
    else:
        print(f"shared logs not found at {SHARED_BETAFLIGHT}; skipped")
    files = log_files(targets)
    ob_python = args.orangebox_python or sys.executable
    ob_env = env_with(args.orangebox_path)
    probe = subprocess.run([ob_python, "-c", "import orangebox"], env=ob_env, capture_output=True)
    ob_cmd = [ob_python, "-c", ORANGEBOX_ALL_LOGS] if probe.returncode == 0 else None
    print(f"load average before: {' '.join(f'{x:.1f}' for x in os.getloadavg())} "
          f"on {os.cpu_count()} CPUs; {args.repeat} alternating runs each, medians")  # fmt: skip
    floor_s = floor_cpu_s(args.repeat)
    for path in files:
        bench_file(path, args.repeat, ob_cmd, ob_env, floor_s)
    print(f"load average after: {' '.join(f'{x:.1f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
