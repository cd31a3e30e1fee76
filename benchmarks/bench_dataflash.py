"""DataFlash (.bin) -> Df: the numpy bulk decoder beside pymavlink's DFReader, same files, one run.

Baseline: pymavlink.DFReader reading the messages Df needs (IMU, BAT/CURR, RCOU, CTUN, ATT, EV)
into arrays. Ours: thrustmap's reader (same fields, as a FlightLog) and reader + Df extraction.
Files: the shared ArduPilot log (../shared/data, skipped when absent) and a larger synthetic
flight written by the project's simulator.

    .venv/bin/python benchmarks/bench_dataflash.py [--minutes 10]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from support import simulate_flight as simulate

from thrustmap.fitting.df import DfOptions, extract
from thrustmap.fitting.flightlogs import dataflash

SHARED = Path(__file__).resolve().parent.parent.parent / "shared/data/flightlogs/ardupilot"
NEEDED = ["IMU", "BAT", "CURR", "RCOU", "CTUN", "ATT", "EV"]


def pymavlink_arrays(path: Path) -> dict[str, np.ndarray]:
    from pymavlink import DFReader

    reader = DFReader.DFReader_binary(str(path))
    rows: dict[str, list[list[float]]] = {}
    while True:
        m = reader.recv_match(type=NEEDED)
        if m is None:
            break
        d = m.to_dict()
        rows.setdefault(m.get_type(), []).append(
            [float(v) for k, v in d.items() if k != "mavpackettype" and isinstance(v, (int, float))]
        )
    return {k: np.asarray(v) for k, v in rows.items()}


def best_of(fn: Callable[[], object], repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def bench(path: Path, label: str, repeat: int) -> None:
    mb = path.stat().st_size / 1e6
    t_base = best_of(lambda: pymavlink_arrays(path), 1)
    t_read = best_of(lambda: dataflash.read(path), repeat)
    t_df = best_of(lambda: extract(dataflash.read(path), DfOptions(mass_kg=1.0)), repeat)
    print(f"{label}: {path.name}, {mb:.1f} MB")
    print(f"  pymavlink DFReader (baseline) {t_base:8.3f} s  {mb / t_base:7.1f} MB/s")
    print(
        f"  thrustmap reader              {t_read:8.3f} s  {mb / t_read:7.1f} MB/s"
        f"  ({t_base / t_read:.0f}x)"
    )
    print(
        f"  thrustmap reader + Df         {t_df:8.3f} s  {mb / t_df:7.1f} MB/s"
        f"  ({t_base / t_df:.0f}x)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0, help="synthetic flight length")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    shared = SHARED / "copter3.4_pxf_3s.bin"
    if shared.exists():
        bench(shared, "shared real log (Copter 3.4)", args.repeat)
    else:
        print(f"shared log not found at {shared}; skipped")
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "synthetic.bin"
        flight = simulate.simulate_hover(
            simulate.HoverSim(duration_s=args.minutes * 60.0, rate_hz=200.0, seed=0)
        )
        simulate.write_dataflash(flight, path)
        bench(path, f"synthetic {args.minutes:g} min flight at 200 Hz", args.repeat)


if __name__ == "__main__":
    main()
