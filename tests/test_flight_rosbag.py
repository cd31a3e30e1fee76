"""Aerostack2 ROS 2 bags (sqlite3 and mcap) read with rosbags: simulated flights, known values."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from thrustmap.core.errors import DataFormatError
from thrustmap.flightlogs import rosbag
from thrustmap.flightlogs.detect import detect, read_head

pytest.importorskip("rosbags")

from support import rosbag_sim as sim  # noqa: E402

BAGS = ["as2_hover_sim_sqlite3", "as2_hover_sim_mcap"]


def _targets(fixtures_dir: Path, name: str) -> list[Path]:
    bag = fixtures_dir / "flightlogs" / name
    return [bag, *sorted(bag.glob("*.db3")), *sorted(bag.glob("*.mcap"))]


def test_fixtures_are_regenerated_by_our_writer(tmp_path: Path, fixtures_dir: Path) -> None:
    sim.write_fixtures(tmp_path)
    for name in BAGS:
        ours = fixtures_dir / "flightlogs" / name
        for f in ours.iterdir():
            assert (tmp_path / name / f.name).read_bytes() == f.read_bytes(), f.name


@pytest.mark.parametrize("name", BAGS)
def test_simulated_bag_values(fixtures_dir: Path, name: str) -> None:
    for target in _targets(fixtures_dir, name):  # the bag directory or its storage file
        assert rosbag.sniff(target, read_head(target))
        flights = rosbag.read(target)
        assert len(flights) == 1
        fl = flights[0]
        assert fl.format == "rosbag" and fl.warnings == []
        assert fl.metadata["namespace"] == "/drone0"
        assert fl.metadata["time_source"] == "header.stamp"
        assert fl.metadata["storage"] == ("mcap" if "mcap" in name else "sqlite3")
        assert fl.thrust_cmd_n is not None and fl.thrust_cmd_norm is not None
        t = fl.thrust_cmd_n.time_s
        np.testing.assert_allclose(t, np.arange(120) / 20, atol=1e-9)
        expected = np.array([sim.thrust_n(x) for x in t])
        np.testing.assert_allclose(fl.thrust_cmd_n.values, expected, rtol=1e-6)  # float32
        assert fl.thrust_cmd_n.unit == "N" and "thrust" in fl.thrust_cmd_n.origin
        assert fl.accel_up_mps2 is not None and fl.voltage_v is not None
        ta = fl.accel_up_mps2.time_s
        np.testing.assert_allclose(fl.accel_up_mps2.values, [sim.accel_up(x) for x in ta])
        assert fl.extras["accel_y_mps2"].values[0] == pytest.approx(-0.02)
        tv = fl.voltage_v.time_s
        np.testing.assert_allclose(fl.voltage_v.values, [sim.voltage_v(x) for x in tv], rtol=1e-6)
        assert fl.extras["current_a"].values[0] == pytest.approx(-12.5)
        assert fl.armed is not None and fl.landed is not None
        probe = np.array([0.2, 0.6, 1.5, 3.0, 5.2, 5.9])
        np.testing.assert_array_equal(fl.armed.hold(probe), [0, 1, 1, 1, 1, 0])
        np.testing.assert_array_equal(fl.landed.hold(probe), [1, 1, 1, 0, 1, 1])
        np.testing.assert_array_equal(fl.extras["platform_state"].hold(probe), [0, 1, 2, 3, 4, 0])
        assert fl.extras["position_z_m"].hold(np.array([3.0]))[0] == 1.0


def test_namespace_option(fixtures_dir: Path) -> None:
    bag = fixtures_dir / "flightlogs" / BAGS[0]
    assert rosbag.read(bag, namespace="drone0")[0].metadata["namespace"] == "/drone0"
    with pytest.raises(DataFormatError, match="namespace 'drone7'.*'/drone0'"):
        rosbag.read(bag, namespace="drone7")


def test_other_namespace_is_detected(tmp_path: Path) -> None:
    a = sim.write_simulated_bag(tmp_path / "a", "sqlite3", namespace="/drone1")
    flights = rosbag.read(a)
    assert [f.metadata["namespace"] for f in flights] == ["/drone1"]


def test_bag_receive_time_option(fixtures_dir: Path) -> None:
    fl = rosbag.read(fixtures_dir / "flightlogs" / BAGS[1], use_header_stamps=False)[0]
    assert fl.metadata["time_source"] == "bag receive time"
    assert fl.thrust_cmd_n is not None and fl.thrust_cmd_n.time_s[1] == pytest.approx(0.05)


def test_platform_info_prefix_survives_a_different_tail() -> None:
    """An older as2_msgs ControlMode (no header) changes only the tail of PlatformInfo."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    defs = dict(rosbag.AS2_MSG_DEFS)
    defs["as2_msgs/msg/ControlMode"] = "int8 yaw_mode\nint8 control_mode\nint8 reference_frame\n"
    types: dict[str, object] = {}
    for name, text in defs.items():
        types.update(get_types_from_msg(text, name))
    ts.register(types)
    T = ts.types
    msg = T["as2_msgs/msg/PlatformInfo"](
        header=T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=12, nanosec=5), frame_id="drone_with_a_long_name"
        ),
        connected=True, armed=True, offboard=False,
        status=T["as2_msgs/msg/PlatformStatus"](state=3),
        current_control_mode=T["as2_msgs/msg/ControlMode"](yaw_mode=1, control_mode=2, reference_frame=1),
    )  # fmt: skip
    raw = bytes(ts.serialize_cdr(msg, "as2_msgs/msg/PlatformInfo"))
    assert rosbag.platform_info_prefix(raw) == (12_000_000_005, 1.0, 3.0)


def test_detect_picks_the_rosbag_reader(fixtures_dir: Path) -> None:
    for target in _targets(fixtures_dir, BAGS[1]):
        assert detect(target).name == "rosbag"


def test_not_a_bag_and_empty_bag(tmp_path: Path) -> None:
    (tmp_path / "x.db3").write_bytes(b"SQLite format 3\x00" + b"\x00" * 100)
    assert rosbag.sniff(tmp_path / "x.db3", read_head(tmp_path / "x.db3"))
    with pytest.raises(DataFormatError, match="cannot open ROS 2 bag"):
        rosbag.read(tmp_path / "x.db3")
    from rosbags.rosbag2 import Writer

    with Writer(tmp_path / "empty", version=9) as w:
        w.add_connection("/other/topic", "std_msgs/msg/String", typestore=rosbag.as2_typestore())
    with pytest.raises(DataFormatError, match="no Aerostack2 topics"):
        rosbag.read(tmp_path / "empty")
    assert not rosbag.sniff(tmp_path, b"")


def test_missing_rosbags_names_the_extra(
    monkeypatch: pytest.MonkeyPatch, fixtures_dir: Path
) -> None:
    monkeypatch.setitem(sys.modules, "rosbags.highlevel", None)
    with pytest.raises(DataFormatError, match=r"thrustmap\[rosbag\]"):
        rosbag.read(fixtures_dir / "flightlogs" / BAGS[0])
    # sniffing needs no optional package
    assert rosbag.sniff(fixtures_dir / "flightlogs" / BAGS[0], b"")
