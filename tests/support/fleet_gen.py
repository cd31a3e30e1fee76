"""A synthetic fleet: several airframes, batteries and firmware formats, and a few corrupt files.

Each airframe is a firmware format (PX4 ULog, its pre-1.14 generation, ArduPilot DataFlash,
ArduCopter ≤ 3.3 DataFlash) with its own mass and its own γ(B); each log flies a different slice
of a 6S battery. Masses are given to ``fleet extract`` by a ``pattern,mass_kg`` CSV keyed on the
file-name prefix. ``make_fleet`` returns what was written, so tests know the truth.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from support import simulate_flight as sim


@dataclass(frozen=True)
class Airframe:
    name: str
    writer: str  # ulog | ulog-legacy | dataflash | dataflash-old
    mass_kg: float
    gamma: tuple[float, ...]
    start_v: tuple[float, float] = (22.6, 25.2)  # each log starts at a voltage in this range
    drop_v: tuple[float, float] = (0.8, 1.6)  # and flies its battery down by this much


AIRFRAMES = (
    Airframe("px4quad", "ulog", 1.0, sim.default_gamma()),
    Airframe("px4old", "ulog-legacy", 1.4, (1.05,)),
    Airframe("apquad", "dataflash", 1.2, sim.default_gamma(25.0)),
    Airframe("copter3", "dataflash-old", 0.9, (1.6, -0.02)),
)
#: an airframe flown on one battery level only (a γ slope cannot be fitted), and a small one
NARROW = Airframe("narrow", "dataflash", 2.0, (1.1,), start_v=(23.0, 23.02), drop_v=(0.05, 0.1))
FEW = Airframe("few", "ulog", 0.7, (1.2,))
SUFFIX = {"ulog": ".ulg", "ulog-legacy": ".ulg", "dataflash": ".bin", "dataflash-old": ".bin"}
#: files that are not flight logs, and the reason they must be refused for (a word in it)
CORRUPT = {
    "corrupt-empty.ulg": (b"", "empty"),
    "corrupt-noise.bin": (
        bytes(np.random.default_rng(5).integers(0, 256, 3000, dtype=np.uint8)),
        "unrecognised",
    ),  # fmt: skip
    "corrupt-text.ulg": (b"this is not a flight log\n" * 20, "unrecognised"),
    "corrupt-header.ulg": (b"ULog\x01\x12\x35\x01\x00\x00", ""),
}


@dataclass
class Fleet:
    folder: Path
    masses_csv: Path
    stand_map: Path
    good: dict[Path, Airframe] = field(default_factory=dict)
    corrupt: dict[Path, str] = field(default_factory=dict)
    no_mass: list[Path] = field(default_factory=list)


def write_log(af: Airframe, flight: sim.SimFlight, path: Path) -> None:
    if af.writer == "ulog":
        sim.write_ulog(flight, path)
    elif af.writer == "ulog-legacy":
        sim.write_ulog(flight, path, legacy=True)
    elif af.writer == "dataflash":
        sim.write_dataflash(flight, path)
    else:
        sim.write_dataflash(flight, path, old_firmware=True)


def make_fleet(
    root: Path,
    logs_per_airframe: int,
    *,
    duration_s: float = 24.0,
    rate_hz: float = 12.5,
    airframes: tuple[Airframe, ...] = AIRFRAMES,
    extra: dict[Airframe, int] | None = None,
    corrupt: bool = True,
    no_mass: int = 1,
    seed: int = 0,
) -> Fleet:
    """Write the fleet under ``root/logs`` (a sub-folder per airframe, corrupt files at the top),
    with ``root/masses.csv`` and the stand map ``root/stand-map.json`` beside it."""
    tmap = sim.sim_stand_map()
    fleet = Fleet(root / "logs", root / "masses.csv", root / "stand-map.json")
    folder = fleet.folder
    folder.mkdir(parents=True, exist_ok=True)
    tmap.save(fleet.stand_map)
    rng = np.random.default_rng(seed)
    lines = ["pattern,mass_kg"]
    counts = [(af, logs_per_airframe) for af in airframes] + list((extra or {}).items())
    for ai, (af, count) in enumerate(counts):
        sub = folder / af.name
        sub.mkdir(exist_ok=True)
        lines.append(f"{af.name}-*,{af.mass_kg}")
        for k in range(count):
            start = float(rng.uniform(*af.start_v))
            hs = sim.HoverSim(
                mass_kg=af.mass_kg,
                duration_s=duration_s,
                rate_hz=rate_hz,
                voltage_start_v=start,
                voltage_end_v=start - float(rng.uniform(*af.drop_v)),
                gamma=af.gamma,
                seed=seed * 100_000 + ai * 10_000 + k,
            )
            path = sub / f"{af.name}-{k:04d}{SUFFIX[af.writer]}"
            write_log(af, sim.simulate_hover(hs, tmap), path)
            fleet.good[path] = af
    for i in range(no_mass):  # a vehicle nobody gave the mass of: refused with that reason
        af = airframes[0]
        path = folder / f"unknown-{i}{SUFFIX[af.writer]}"
        hs = sim.HoverSim(duration_s=duration_s, rate_hz=rate_hz, seed=seed + 7 + i)
        write_log(af, sim.simulate_hover(hs, tmap), path)
        fleet.no_mass.append(path)
    if corrupt:
        for name, (data, word) in CORRUPT.items():
            (folder / name).write_bytes(data)
            fleet.corrupt[folder / name] = word
    fleet.masses_csv.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return fleet
