"""Regenerate every test fixture the project ships, from the generators in this folder.

    cd tests && python -m support.regenerate [FIXTURES_DIR]     (default: ../fixtures)

Each generator is deterministic (seeded simulations on a simulated clock); only creation
timestamps differ between runs. ``tests/test_fixtures_fresh.py`` regenerates into a temporary
folder and fails when a shipped fixture no longer matches its generator.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from support import (
    blackbox_encode,
    diy_stand_recordings,
    mavlink_transcripts,
    rosbag_sim,
    simulate_flight,
    stand_recordings,
    sweep_recordings,
    telemetry_flight,
)

DEFAULT_DIR = Path(__file__).resolve().parents[2] / "fixtures"


def regenerate(fixtures: Path) -> list[Path]:
    """Write every fixture under ``fixtures`` (flightlogs/, transcripts/, sweeps/, stands/)."""
    flightlogs = fixtures / "flightlogs"
    written: list[Path] = list(simulate_flight.write_fixtures(flightlogs))
    written += [Path(p) for p in blackbox_encode.write_fixtures(str(flightlogs))]
    written += list(rosbag_sim.write_fixtures(flightlogs))
    written += telemetry_flight.write_fixture(flightlogs)
    transcripts = fixtures / "transcripts"
    mavlink_transcripts.main([str(transcripts)])
    written += sorted(transcripts.glob("*.jsonl"))
    sweeps = fixtures / "sweeps"
    for flavour in sweep_recordings.FLAVOURS:
        sweep_recordings.record(flavour, sweeps)
    written += sorted(p for p in sweeps.iterdir() if p.is_file())
    written += stand_recordings.write_fixtures(fixtures / "stands")
    written += diy_stand_recordings.write_fixtures(fixtures / "stands")
    return written


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("fixtures", nargs="?", type=Path, default=DEFAULT_DIR)
    args = parser.parse_args()
    for path in regenerate(args.fixtures):
        print(path)  # noqa: T201 - a developer tool


if __name__ == "__main__":
    main()
