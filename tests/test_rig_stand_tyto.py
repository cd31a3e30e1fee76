"""The Tyto 1585 calibration FILE (rig/stand/tyto.py; the codec in protocols/ only converts):
round trip, and errors in the project's one JSON error style naming the file and the field."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from thrustmap.core.errors import DataFormatError, ThrustmapError
from thrustmap.protocols.stands.tyto import LoadCell, TytoCalibration
from thrustmap.rig.stand.tyto import (
    calibration_to_dict,
    load_calibration,
    save_calibration,
    simulated_calibration,
)

CAL = TytoCalibration(
    thrust=LoadCell(tare=1000.0, n_per_count=-0.001),
    torque_left=LoadCell(tare=50.0, n_per_count=0.0005),
    torque_right=LoadCell(tare=-20.0, n_per_count=0.0004),
    arm_length_m=0.04,
    electrical_rpm_factor=1.0 / 7.0,
    vibration_g_per_count=0.01,
    serial="unit-7",
)


def test_calibration_file_round_trip(tmp_path: Path) -> None:
    path = tmp_path / "cal.json"
    save_calibration(CAL, path)
    assert load_calibration(path) == CAL
    plain = TytoCalibration(CAL.thrust, CAL.torque_left, CAL.torque_right, 0.05)
    save_calibration(plain, path)  # optional fields absent -> their defaults
    assert load_calibration(path) == plain


def test_calibration_errors_name_file_and_field(tmp_path: Path) -> None:
    path = tmp_path / "cal.json"
    data = calibration_to_dict(CAL)
    data["torque"]["left"]["n_per_count"] = 0
    path.write_text(json.dumps(data))
    with pytest.raises(DataFormatError) as err:
        load_calibration(path)
    assert "field 'torque.left.n_per_count'" in str(err.value) and str(path) in str(err.value)
    assert "non-zero" in str(err.value)

    del data["torque"]["arm_length_m"]
    data["torque"]["left"]["n_per_count"] = 1e-3
    path.write_text(json.dumps(data))
    with pytest.raises(DataFormatError, match=r"'torque.arm_length_m': missing"):
        load_calibration(path)

    path.write_text('{"format": "thrustmap.tyto-calibration",\n "version": 1,,}')
    with pytest.raises(DataFormatError) as err:
        load_calibration(path)
    assert err.value.line == 2

    path.write_text(json.dumps({"format": "something-else"}))
    with pytest.raises(DataFormatError, match="'format'.*thrustmap.tyto-calibration"):
        load_calibration(path)

    data = calibration_to_dict(CAL)
    data["thrust"]["tare"] = "12"
    path.write_text(json.dumps(data))
    with pytest.raises(DataFormatError, match=r"'thrust.tare': expected a number"):
        load_calibration(path)

    with pytest.raises(ThrustmapError, match="cannot read Tyto calibration"):
        load_calibration(tmp_path / "absent.json")


def test_the_simulator_registers_its_calibration() -> None:
    from thrustmap.rig.devices.urls import load_sim_peers
    from thrustmap.rig.sim.stand_peers import SIM_TYTO_CALIBRATION

    load_sim_peers()
    assert simulated_calibration("tyto-1585") == SIM_TYTO_CALIBRATION
    assert simulated_calibration("no-such") is None
