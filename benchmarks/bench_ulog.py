"""ULog -> Df beside plain pyulog (parsing the same topics), same files, one run.

thrustmap's ULog reader is pyulog plus normalisation, an integrity walk of the message headers
and Df extraction; this shows what that costs on top of pyulog alone.

    .venv/bin/python benchmarks/bench_ulog.py [--minutes 10]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from support import simulate_flight as simulate

from thrustmap.fitting.df import DfOptions, extract
from thrustmap.fitting.flightlogs import ulog

SHARED = Path(__file__).resolve().parent.parent.parent / "shared/data/flightlogs/px4"


def best_of(fn: Callable[[], object], repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def bench(path: Path, label: str, repeat: int) -> None:
    from pyulog import ULog

    mb = path.stat().st_size / 1e6
    t_py = best_of(lambda: ULog(str(path), message_name_filter_list=ulog.TOPICS), repeat)
    t_read = best_of(lambda: ulog.read(path), repeat)
    t_df = best_of(lambda: extract(ulog.read(path), DfOptions(mass_kg=1.0)), repeat)
    print(f"{label}: {path.name}, {mb:.1f} MB")
    print(f"  pyulog, same topics (baseline) {t_py:8.3f} s  {mb / t_py:7.1f} MB/s")
    print(
        f"  thrustmap reader               {t_read:8.3f} s  {mb / t_read:7.1f} MB/s"
        f"  ({t_read / t_py:.2f}x the baseline time)"
    )
    print(
        f"  thrustmap reader + Df          {t_df:8.3f} s  {mb / t_df:7.1f} MB/s"
        f"  ({t_df / t_py:.2f}x the baseline time)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=5.0, help="synthetic flight length")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    for name in ("sitl_v1.15_sample_px4_events.ulg", "fmuv3_v1.9_esc_status.ulg"):
        p = SHARED / name
        if p.exists():
            bench(p, "shared real log", args.repeat)
        else:
            print(f"shared log not found at {p}; skipped")
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "synthetic.ulg"
        flight = simulate.simulate_hover(
            simulate.HoverSim(duration_s=args.minutes * 60.0, rate_hz=200.0, seed=0)
        )
        simulate.write_ulog(flight, path)
        bench(path, f"synthetic {args.minutes:g} min flight at 200 Hz", args.repeat)


if __name__ == "__main__":
    main()
