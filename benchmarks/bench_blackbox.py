"""Blackbox .bbl decoding throughput: thrustmap's own decoder beside orangebox (GPL-3, only if
it happens to be importable — never a dependency) or, without it, the figure flight-logs.md
quotes for orangebox (0.5–0.9 MB/s).

Run: .venv/bin/python benchmarks/bench_blackbox.py [LOG.bbl]
(default: ../shared/data/flightlogs/betaflight/bf4.2.8_4s.bbl, else the project's fixture)
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from thrustmap.fitting.flightlogs import blackbox
from thrustmap.fitting.flightlogs.blackbox_decode import decode_file

ROOT = Path(__file__).resolve().parent.parent


def best_of(n: int, fn: object) -> float:
    times = []
    for _ in range(n):
        t = time.perf_counter()
        fn()  # type: ignore[operator]
        times.append(time.perf_counter() - t)
    return min(times)


def main() -> None:
    if len(sys.argv) > 1:
        path = Path(sys.argv[1])
    else:
        path = ROOT.parent / "shared/data/flightlogs/betaflight/bf4.2.8_4s.bbl"
        if not path.is_file():
            path = ROOT / "fixtures/flightlogs/bb_hover_sim.bbl"
    data = path.read_bytes()
    mb = len(data) / 1e6
    frames = sum(len(lg.main) for lg in decode_file(data))
    t_decode = best_of(3, lambda: decode_file(data))
    t_read = best_of(3, lambda: blackbox.read(path))
    print(f"{path.name}: {mb:.2f} MB, {frames} main frames")
    print(f"thrustmap decode_file     : {mb / t_decode:6.2f} MB/s ({t_decode:.2f} s)")
    print(
        f"thrustmap blackbox.read   : {mb / t_read:6.2f} MB/s ({t_read:.2f} s, incl. normalisation)"
    )
    try:
        from orangebox import Parser  # type: ignore[import-not-found]
    except ImportError:
        print("orangebox (baseline)      :   0.5–0.9 MB/s (quoted; not installed here)")
        return

    def orange() -> None:
        parser = Parser.load(str(path))
        for _ in parser.frames():
            pass

    t_ob = best_of(1, orange)
    print(f"orangebox (baseline)      : {mb / t_ob:6.2f} MB/s ({t_ob:.2f} s)")
    print(f"speed-up                  : {t_ob / t_decode:6.1f}x")


if __name__ == "__main__":
    main()
