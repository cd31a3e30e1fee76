"""Every shipped fixture matches what its generator in tests/support writes today."""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path

import pytest
from support.regenerate import regenerate

FIXTURES = Path(__file__).resolve().parent.parent / "fixtures"
#: fields that record when a file was made, not what it says
VOLATILE = re.compile(rb'"(created_utc|started_utc|ended_utc)": ?"[^"]*"')


def _normalised(path: Path) -> bytes:
    data = path.read_bytes()
    if path.suffix in (".jsonl", ".json"):
        return VOLATILE.sub(rb'"\1":"-"', data.replace(b'": "', b'":"'))
    return data


@pytest.fixture(scope="module")
def regenerated(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("fixtures")
    (out / "sweeps").mkdir()
    # the sweep recordings need the shipped calibration beside them, as a user's rig would
    regenerate(out)
    return out


def _recorded(path: Path) -> bool:
    """A hand-written README, or a recording of a real program that no generator here can
    write: one the README beside it vouches for by its sha256 (a stand firmware's authors'
    emulator), or one in a folder with a ``provenance.json`` (real firmware compiled on the
    Arduino shim by ``tests/support/arduino_shim``, whose own test pins the shim)."""
    if path.name == "README.md" or (path.parent / "provenance.json").is_file():
        return True
    readme = path.parent / "README.md"
    if not readme.is_file():
        return False
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    return ".recorded." in path.name and digest in readme.read_text(encoding="utf-8")


def _shipped() -> list[Path]:
    skip = {"metadata.yaml"}  # rosbag metadata carries the writer's own timestamps
    files = [p for p in FIXTURES.rglob("*") if p.is_file() and p.name not in skip]
    # recordings of real firmware: no generator can remake them; their sha256 is checked
    # against fixtures/firmware/*/MANIFEST.json by tests/test_firmware_recordings.py
    files = [p for p in files if p.relative_to(FIXTURES).parts[0] != "firmware"]
    return sorted(p for p in files if not p.name.startswith(".") and not _recorded(p))


@pytest.mark.parametrize("shipped", _shipped(), ids=lambda p: str(p.relative_to(FIXTURES)))
def test_fixture_is_fresh(shipped: Path, regenerated: Path) -> None:
    rel = shipped.relative_to(FIXTURES)
    fresh = regenerated / rel
    assert fresh.exists(), f"{rel} is shipped but no generator writes it (delete it or add one)"
    if _normalised(fresh) != _normalised(shipped):
        pytest.fail(f"{rel} is stale: run `cd tests && python -m support.regenerate`")


def test_every_generated_fixture_is_shipped(regenerated: Path) -> None:
    made = {p.relative_to(regenerated) for p in regenerated.rglob("*") if p.is_file()}
    shipped = {p.relative_to(FIXTURES) for p in FIXTURES.rglob("*") if p.is_file()}
    assert made <= shipped, f"generated but not shipped: {sorted(map(str, made - shipped))}"


def test_sidecar_timestamps_are_the_only_volatile_fields() -> None:
    meta = json.loads((FIXTURES / "sweeps" / "msp_run.meta.json").read_text())
    assert {"started_utc", "ended_utc"} <= set(meta)
