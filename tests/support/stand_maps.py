"""Maps fitted from the shared real stand recordings (../shared/data), for the export tests.

Test support only. ``THRUSTMAP_SHARED_DATA`` points elsewhere when the checkout does not sit
beside ``shared`` (a worktree); tests skip when neither is found.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

from thrustmap.fitting.fit.fitmap import fit_map
from thrustmap.fitting.loaders.load import load_dataset
from thrustmap.fitting.mapfile import ThrustMap

PROJECT_ROOT = Path(__file__).resolve().parents[2]


def shared_data() -> Path | None:
    env = os.environ.get("THRUSTMAP_SHARED_DATA")
    for candidate in ([Path(env)] if env else []) + [PROJECT_ROOT.parent / "shared" / "data"]:
        if candidate.is_dir():
            return candidate
    return None


def stand_sets() -> dict[str, tuple[Path, ...]]:
    """Every shared stand recording, grouped as one map is fitted from them (name -> files)."""
    root = shared_data()
    if root is None:
        return {}
    out: dict[str, tuple[Path, ...]] = {}
    xnova = root / "xnova-thrust-stand"
    for rig in ("single_rotor", "multirotor"):
        files = sorted(p for p in (xnova / rig).glob("*.csv") if "-TM-" not in p.name)
        if files:
            out[f"xnova-{rig}"] = tuple(files)
        for tm in sorted((xnova / rig).glob("*-TM-*.csv")):
            out[f"xnova-{tm.stem}"] = (tm,)
    for stand in sorted((root / "third-party-stands").glob("*")):
        if not stand.is_dir():
            continue
        pairs: dict[str, list[Path]] = {}
        for f in sorted(stand.glob("*.csv")):
            pairs.setdefault(f.stem.rsplit("_", 1)[0], []).append(f)
        for key, files in pairs.items():
            out[f"{stand.name}-{key}"] = tuple(files)
    return out


@functools.cache
def stand_map(name: str) -> ThrustMap:
    files = stand_sets()[name]
    return fit_map([load_dataset(f) for f in files]).map
