"""Issue 13 acceptance: on every ArduPilot and PX4 log in ../shared/data/flightlogs,
``thrustmap flightlog extract LOG --mass-kg M -o df.csv`` (no map) keeps only steady flight.

Steady flight means the normalised thrust command per unit of upward specific force is a smooth
function of the battery voltage: fitted as a straight line in B, at most 3 % of the Df samples
lie more than 10 % off it (spool-up on the ground, takeoff ramps, saturated commands and wrong
rotor counts all break that). Every log must succeed: a Df shorter than 50 samples says why, a
log without steady flight gives an empty Df and says why, and a log without battery voltage
gives a Df with an empty voltage column and one warning (its ratio is then judged as flat).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from thrustmap.cli.flight import flightlog_group

MIN_SAMPLES = 50
MAX_OFF_FRACTION = 0.03
OFF_RELATIVE = 0.10


def _logs(shared: Path) -> list[Path]:
    base = shared / "flightlogs"
    return sorted((base / "ardupilot").glob("*.bin")) + sorted((base / "px4").glob("*.ulg"))


def _extract(log: Path, out: Path) -> tuple[int, str]:
    res = CliRunner().invoke(
        flightlog_group, ["extract", str(log), "--mass-kg", "1.5", "-o", str(out)]
    )
    text = res.output + (str(res.exception) if res.exception is not None else "")
    return res.exit_code, text


def test_every_shared_log_keeps_only_steady_flight(shared_data: Path, tmp_path: Path) -> None:
    logs = _logs(shared_data)
    if not logs:
        pytest.skip("no ArduPilot/PX4 logs in ../shared/data/flightlogs")
    judged = 0
    for log in logs:
        out = tmp_path / f"{log.stem}.csv"
        code, text = _extract(log, out)
        assert code == 0, (log.name, text)  # every ArduPilot/PX4 log gives a Df
        table = pd.read_csv(out)
        if not len(table):  # an empty Df says why, naming the log and the filters
            assert "no steady flight to extract (0 samples" in text and log.name in text, text
            continue
        if len(table) < MIN_SAMPLES:
            assert f"only {len(table)} samples of steady flight" in text, (log.name, text)
            continue
        ratio = (table["thrust_cmd_norm"] / table["accel_up_mps2"]).to_numpy(float)
        volt = table["voltage_v"].to_numpy(float)
        if np.isnan(volt).all():  # no battery voltage: said once, and the ratio judged as flat
            assert f"{log.name}#0: battery voltage unknown" in text, (log.name, text)
            line = np.full(len(ratio), float(np.median(ratio)))
        else:
            line = np.polyval(np.polyfit(volt, ratio, 1), volt)
        off = np.abs(ratio / line - 1.0) > OFF_RELATIVE
        assert off.mean() <= MAX_OFF_FRACTION, (log.name, f"{off.mean():.1%} off the line")
        judged += 1
    assert judged >= 1 or len(logs) < 3  # the 3.4 logs have long steady flights


def test_no_voltage_still_gives_a_df_and_says_what_it_costs(
    shared_data: Path, tmp_path: Path
) -> None:
    """Copter 3.3 on an Erle PXF logs CURR.Volt = 0 (no sensor); the appended-data ULog has no
    battery_status at all. Both give a Df with an empty voltage column and one warning that
    names the reason and what it costs."""
    cases = {
        "ardupilot/copter3.3_althold_pxf.bin": "CURR.Volt reads 0 V throughout",
        "px4/pyulog_sample_appended_multiple.ulg": "no battery_status",
    }
    for rel, reason in cases.items():
        log = shared_data / "flightlogs" / rel
        if not log.exists():
            continue
        out = tmp_path / "df.csv"
        code, text = _extract(log, out)
        assert code == 0, (rel, text)
        warned = [ln for ln in text.splitlines() if "battery voltage unknown" in ln]
        assert len(warned) == 1 and reason in warned[0], (rel, text)
        assert "γ can only be fitted as a constant" in warned[0]
        table = pd.read_csv(out)
        assert "voltage_v" in table.columns and table["voltage_v"].isna().all(), rel
