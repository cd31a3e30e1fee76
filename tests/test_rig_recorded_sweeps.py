"""Recorded full sweeps (MSP and PX4/MAVLink flavours, with a Tyto stand) replay through the real
drivers and runner, strictly: every byte written must match the recording, everything recorded
must be used, and the Ds log must come out identical to the one recorded."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from support import sweep_recordings as recordings

from thrustmap.fitting.loaders.load import load_dataset
from thrustmap.protocols.transcript import read_transcript

FIXTURES = Path(__file__).resolve().parent.parent / "fixtures" / "sweeps"


@pytest.mark.parametrize("flavour", sorted(recordings.FLAVOURS))
def test_recorded_sweep_replays_byte_for_byte(tmp_path: Path, flavour: str) -> None:
    fc_log, stand_log, recorded_csv = recordings.paths(flavour, FIXTURES)
    result, ports = recordings.replay(flavour, FIXTURES, tmp_path / "run.csv")
    assert result.status == "completed" and result.stop_verified
    for port in ports:
        port.assert_consumed()  # every recorded write matched, every recorded read served
    assert (tmp_path / "run.csv").read_bytes() == recorded_csv.read_bytes()
    # decoded values, not just bytes: four stairs 10..40 %, thrust rising with throttle
    ds = load_dataset(tmp_path / "run.csv")
    levels = sorted({round(float(p)) for p in ds.throttle_pct})
    assert {10, 20, 30, 40} <= set(levels)
    means = [
        float(np.mean(ds.thrust_n[np.isclose(ds.throttle_pct, lv)][-20:]))
        for lv in (10, 20, 30, 40)
    ]
    assert all(b > a + 0.2 for a, b in zip(means, means[1:], strict=False)), means
    assert 20.0 < float(np.median(ds.voltage_v)) < 25.3  # a 6S pack
    # the transcript ends with the stop sequence and nothing after it reaches the FC
    written = read_transcript(fc_log).written()
    assert written, "FC transcript has writes"
    meta = json.loads(recordings.paths(flavour, FIXTURES)[2].with_suffix(".meta.json").read_text())
    assert meta["outcome"]["status"] == "completed" and meta["stop_verified"] is True


def _replay_with_plan(tmp_path: Path, new_plan: Any, *, match: str) -> tuple[Any, list[Any]]:
    original = recordings.plan
    recordings.plan = new_plan
    try:
        return recordings.replay("msp", FIXTURES, tmp_path / "run.csv", match=match)
    finally:
        recordings.plan = original


def test_a_changed_driver_is_caught_byte_for_byte(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """With match=bytes, strict replay fails the moment the code writes a byte the recording
    does not have (here: a shorter dwell, so the next step's command comes early)."""
    from thrustmap.rig import plans

    result, ports = _replay_with_plan(
        tmp_path, lambda: plans.stairs(10, 40, 10, dwell_s=1.4), match="bytes"
    )
    # the first differing write is refused, the runner aborts, and the transcript is not used up
    assert result.status == "aborted"
    report = ports[0].report()
    assert not report.fully_consumed and report.write_bytes_remaining > 0
    # the refusal names the first differing byte (the runner saw it as a failing link and stopped)
    assert any("write-stream byte" in r.getMessage() for r in caplog.records)


def test_message_replay_tolerates_cadence_but_catches_a_changed_command(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """By message (the default), a shorter dwell only changes how many keep-alives are sent: it
    replays. A higher throttle than recorded is a real divergence, named in message terms."""
    from thrustmap.rig import plans

    result, ports = _replay_with_plan(
        tmp_path, lambda: plans.stairs(10, 40, 10, dwell_s=1.4), match="auto"
    )
    assert result.status == "completed" and result.stop_verified
    assert ports[0].report().match == "messages" and ports[0].report().unanswered == ""
    caplog.clear()
    result, ports = _replay_with_plan(
        tmp_path / "b", lambda: plans.stairs(10, 50, 20, dwell_s=1.5), match="auto"
    )
    assert result.status == "aborted"
    text = " ".join(r.getMessage() for r in caplog.records)
    # the recording's motor went to 40 % (1400 us) and stopped; this driver ramps on to 50 %
    assert re.search(r"expected SET_MOTOR 1000 [0 1]+, driver sent SET_MOTOR 1[45]\d0 ", text)
    assert result.stop_verified


def test_fixtures_regenerate_identically(tmp_path: Path) -> None:
    for flavour in recordings.FLAVOURS:
        recordings.record(flavour, tmp_path)
        for shipped, fresh in zip(
            recordings.paths(flavour, FIXTURES), recordings.paths(flavour, tmp_path), strict=True
        ):
            if shipped.suffix == ".jsonl":
                assert read_transcript(fresh).events == read_transcript(shipped).events
            else:
                assert fresh.read_bytes() == shipped.read_bytes()
