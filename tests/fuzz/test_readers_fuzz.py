"""Mutation corpus over every file reader: bit flips, truncations, splices, cut-outs and boundary
values written over our own fixtures. Each input runs in a forked child limited in time and
memory (tests/fuzz/harness.py); the only acceptable outcomes are a result or a ThrustmapError.

CI runs FUZZ_COUNT mutants per reader (a few seconds in all); ``THRUSTMAP_FUZZ_LONG=1`` (or
``benchmarks/fuzz_long.py``) runs many more with other seeds.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from fuzz.harness import describe, failures, mutants, run_bounded

ROOT = Path(__file__).resolve().parents[2]
LOGS = ROOT / "fixtures" / "flightlogs"
SWEEPS = ROOT / "fixtures" / "sweeps"
TRANSCRIPTS = ROOT / "fixtures" / "transcripts"

LONG = os.environ.get("THRUSTMAP_FUZZ_LONG", "") not in ("", "0")
FUZZ_COUNT = 400 if LONG else 24
SEEDS = range(1, 6) if LONG else range(1, 2)
TIMEOUT_S = 10.0


def _flight(fmt: str) -> Callable[[Path], Any]:
    def read(path: Path) -> Any:
        from thrustmap.flightlogs.detect import read_log

        return read_log(path, format=fmt)

    return read


def _auto_flight(path: Path) -> Any:
    from thrustmap.flightlogs.detect import read_log

    return read_log(path)


def _extract(path: Path) -> Any:
    """Flight log all the way to Df: the time-span bound and the resampling."""
    from thrustmap.fitting.df.extraction import extract
    from thrustmap.fitting.df_options import DfOptions
    from thrustmap.flightlogs.detect import read_log

    flights = read_log(path)
    return extract(flights, DfOptions(mass_kg=1.0))


def _stand(path: Path) -> Any:
    from thrustmap.fitting.loaders.load import load_dataset

    return load_dataset(path)


def _map(path: Path) -> Any:
    from thrustmap.fitting.mapfile import ThrustMap

    tmap = ThrustMap.load(path)
    return tmap.thrust_n(50.0, 16.0)


def _df(path: Path) -> Any:
    from thrustmap.fitting.df.dffile import read_df

    return read_df(path)


def _transcript(path: Path) -> Any:
    from thrustmap.protocols.transcript import read_transcript

    return read_transcript(path)


def _tyto_calibration(path: Path) -> Any:
    from thrustmap.rig.stand.tyto import load_calibration

    return load_calibration(path)


def _df_fixture(tmp: Path) -> bytes:
    from fuzz.cli_cases import df_table

    return df_table()


#: reader name -> (source file, suffix, text-like, function)
READERS: dict[str, tuple[Path, str, bool, Callable[[Path], Any]]] = {
    "ulog": (LOGS / "sim_hover.ulg", ".ulg", False, _flight("ulog")),
    "ulog-v1.9": (LOGS / "sim_hover_v1.9.ulg", ".ulg", False, _flight("ulog")),
    "dataflash": (LOGS / "sim_hover.bin", ".bin", False, _flight("dataflash")),
    "dataflash-copter3": (LOGS / "sim_hover_copter3.bin", ".bin", False, _flight("dataflash")),
    "tlog": (LOGS / "sim_hover.tlog", ".tlog", False, _flight("tlog")),
    "blackbox": (LOGS / "bb_hover_sim.bbl", ".bbl", False, _flight("blackbox")),
    "blackbox-csv": (LOGS / "bb_hover_sim.01.csv", ".csv", True, _flight("blackbox-csv")),
    "paper-csv": (LOGS / "sim_hover_paper.csv", ".csv", True, _flight("paper-csv")),
    "generic-csv": (LOGS / "sim_hover_generic.csv", ".csv", True, _auto_flight),
    "extract-paper": (LOGS / "sim_hover_paper.csv", ".csv", True, _extract),
    "extract-dataflash": (LOGS / "sim_hover.bin", ".bin", False, _extract),
    "stand-msp": (SWEEPS / "msp_run.csv", ".csv", True, _stand),
    "stand-px4": (SWEEPS / "px4_run.csv", ".csv", True, _stand),
    "map": (LOGS / "sim_map.json", ".json", True, _map),
    "transcript-px4": (TRANSCRIPTS / "px4_spin.jsonl", ".jsonl", True, _transcript),
    "transcript-msp": (SWEEPS / "msp_fc.jsonl", ".jsonl", True, _transcript),
    "tyto-calibration": (SWEEPS / "tyto_calibration.json", ".json", True, _tyto_calibration),
}


@pytest.mark.parametrize("name", sorted(READERS))
def test_reader_survives_mutations(name: str, tmp_path: Path) -> None:
    source, suffix, text, fn = READERS[name]
    if not source.exists():
        pytest.skip(f"fixture {source.name} not present")
    data = source.read_bytes()
    inputs = [m for seed in SEEDS for m in mutants(data, seed, FUZZ_COUNT, text=text)]
    outcomes = run_bounded(fn, inputs, tmp_path, suffix=suffix, timeout_s=TIMEOUT_S)
    assert not failures(outcomes), describe(outcomes)


def test_df_reader_survives_mutations(tmp_path: Path) -> None:
    data = _df_fixture(tmp_path)
    inputs = [m for seed in SEEDS for m in mutants(data, seed, FUZZ_COUNT, text=True)]
    outcomes = run_bounded(_df, inputs, tmp_path, suffix=".csv", timeout_s=TIMEOUT_S)
    assert not failures(outcomes), describe(outcomes)


def test_rosbag_survives_mutations(tmp_path: Path) -> None:
    pytest.importorskip("rosbags")
    import shutil

    from fuzz.harness import Mutant

    src = LOGS / "as2_hover_sim_sqlite3"
    db = next(iter(sorted(src.glob("*.db3"))), None)
    if db is None:
        pytest.skip("no rosbag fixture")
    data = db.read_bytes()
    seeds = list(SEEDS)
    inputs: list[Mutant] = [m for s in seeds for m in mutants(data, s, FUZZ_COUNT // 2)]

    def read(path: Path) -> Any:
        folder = path.with_suffix("")
        folder.mkdir()
        for extra in src.iterdir():
            if extra != db:
                shutil.copy(extra, folder / extra.name)
        shutil.move(str(path), folder / db.name)
        try:
            return _auto_flight(folder)
        finally:
            shutil.rmtree(folder, ignore_errors=True)

    outcomes = run_bounded(read, inputs, tmp_path, suffix=".db3", timeout_s=TIMEOUT_S)
    assert not failures(outcomes), describe(outcomes)
