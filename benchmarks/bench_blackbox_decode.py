"""Blackbox decoding alone, in this process: CPU seconds per file, with this checkout's decoder or
another checkout's (``--tree``), to measure what a change of the decoder moved.

Decodes every log of each file as ``flightlog extract`` does (``decode_log`` with the fields a
flight log uses), ``--repeat`` times, and prints the median CPU time and MB/s. Files: the
Betaflight/INAV logs of benchmarks/public-data.toml (``--manifest``, by name, sha256 checked)
and any given. A change is measured by running the same command against the tree before it:

    git worktree add /tmp/before 0dde25b^
    python benchmarks/bench_blackbox_decode.py --manifest --tree /tmp/before
    python benchmarks/bench_blackbox_decode.py --manifest
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))  # support.public_data: the manifest's files by name
#: the manifest's blackbox sources (as bench_blackbox.py --manifest)
MANIFEST_SOURCES = ("fc-blackbox", "gimbal-ghost", "blackbox-log", "pid-analyzer", "xerox-inav")


def files(manifest: bool, given: list[Path]) -> list[tuple[str, Path]]:
    from support import public_data as pd

    out = []
    if manifest:
        try:
            for source in MANIFEST_SOURCES:
                out += [(n, pd.resolve(n)) for n in pd.names(source=source)]
        except pd.PublicDataError as exc:
            print(f"error: {exc}", file=sys.stderr)
            sys.exit(2)
    return out + [(p.name, p) for p in given]


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("logs", nargs="*", type=Path, help="blackbox files")
    ap.add_argument("--manifest", action="store_true", help="the manifest's blackbox files")
    ap.add_argument("--tree", type=Path, default=ROOT, help="the checkout whose decoder runs")
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    sys.path.insert(0, str(a.tree.resolve()))
    import thrustmap.flightlogs.blackbox_format as blackbox_format
    from thrustmap.flightlogs import blackbox_decode as bd
    from thrustmap.flightlogs.blackbox import used_field

    print(f"decoder of {a.tree.resolve()} ({bd.__file__}); median CPU of {a.repeat} runs")
    for name, path in files(a.manifest, a.logs):
        data = path.read_bytes()
        mb = len(data) / 1e6
        runs = []
        try:
            for _ in range(max(a.repeat, 1)):
                t = time.process_time()
                for i, (start, end) in enumerate(blackbox_format.split_logs(data)):
                    bd.decode_log(data[start:end], i, start, keep_field=used_field)
                runs.append(time.process_time() - t)
        except Exception as exc:  # noqa: BLE001 - an older decoder may fail on a file: say so
            print(f"{name:36s} {mb:6.2f} MB  failed: {type(exc).__name__}: {exc}")
            continue
        cpu = statistics.median(runs)
        rate = mb / max(cpu, 1e-9)
        print(f"{name:36s} {mb:6.2f} MB  decoding {cpu:7.3f} s CPU  {rate:7.1f} MB/s")


if __name__ == "__main__":
    main()
