"""Write a simulated Aerostack2 hover flight as a ROS 2 bag (sqlite3 or mcap) with known values,
for the project's own fixtures. Needs the optional ``rosbags`` package.

Timeline (seconds from the first message): landed and disarmed, armed at 0.5, TAKING_OFF at 1,
FLYING from 2 to 5, LANDING to 5.5, LANDED after; disarmed at 5.8; 6 s in all.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from thrustmap.flightlogs.rosbag import as2_typestore

T0_NS = 1_700_000_000_000_000_000  # header stamps: wall-clock-like epoch nanoseconds
DURATION_S = 6.0
RATES_HZ = {"imu": 25, "thrust": 20, "battery": 10, "info": 10, "pose": 5}
MASS_KG = 1.2
G0 = 9.80665


def state_at(t: float) -> tuple[bool, int]:
    """(armed, PlatformStatus.state) at time t."""
    armed = 0.5 <= t < 5.8
    if t < 1.0:
        return armed, 0 if not armed else 1
    if t < 2.0:
        return armed, 2
    if t < 5.0:
        return armed, 3
    if t < 5.5:
        return armed, 4
    return armed, 1 if armed else 0


def thrust_n(t: float) -> float:
    return MASS_KG * G0 * (1.0 + 0.02 * math.sin(2 * math.pi * t)) if 1.0 <= t < 5.5 else 0.0


def accel_up(t: float) -> float:
    return G0 + (0.05 * math.sin(2 * math.pi * 3 * t) if 2.0 <= t < 5.0 else 0.0)


def voltage_v(t: float) -> float:
    return 16.8 - 0.1 * t  # a linear sag, known exactly


def _stamp(ts: Any, t: float) -> Any:
    ns = T0_NS + round(t * 1e9)
    time_cls = ts.types["builtin_interfaces/msg/Time"]
    header_cls = ts.types["std_msgs/msg/Header"]
    return ns, header_cls(stamp=time_cls(sec=ns // 10**9, nanosec=ns % 10**9), frame_id="drone0")


def write_simulated_bag(
    path: str | Path, storage: str = "sqlite3", namespace: str = "/drone0"
) -> Path:
    """Write the simulated flight to a new bag directory ``path`` (replaced if present)."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    ts = as2_typestore()
    out = Path(path)
    if out.exists():
        shutil.rmtree(out)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    T = ts.types
    vec3, quat = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    cov = np.zeros(9, dtype=np.float64)
    with Writer(out, version=9, storage_plugin=plugin) as writer:
        topics = {
            "thrust": (f"{namespace}/actuator_command/thrust", "as2_msgs/msg/Thrust"),
            "imu": (f"{namespace}/sensor_measurements/imu", "sensor_msgs/msg/Imu"),
            "battery": (f"{namespace}/sensor_measurements/battery", "sensor_msgs/msg/BatteryState"),
            "info": (f"{namespace}/platform/info", "as2_msgs/msg/PlatformInfo"),
            "pose": (f"{namespace}/self_localization/pose", "geometry_msgs/msg/PoseStamped"),
        }
        conns = {k: writer.add_connection(t, m, typestore=ts) for k, (t, m) in topics.items()}
        events: list[tuple[int, str, Any]] = []
        for key, rate in RATES_HZ.items():
            for k in range(int(DURATION_S * rate)):
                t = k / rate
                ns, header = _stamp(ts, t)
                if key == "thrust":
                    f = thrust_n(t)
                    msg = T["as2_msgs/msg/Thrust"](
                        header=header, thrust=f, thrust_normalized=f / 30.0
                    )
                elif key == "imu":
                    msg = T["sensor_msgs/msg/Imu"](
                        header=header,
                        orientation=quat(x=0.0, y=0.0, z=0.0, w=1.0),
                        orientation_covariance=cov,
                        angular_velocity=vec3(x=0.0, y=0.0, z=0.0),
                        angular_velocity_covariance=cov,
                        linear_acceleration=vec3(x=0.01, y=-0.02, z=accel_up(t)),
                        linear_acceleration_covariance=cov,
                    )
                elif key == "battery":
                    msg = T["sensor_msgs/msg/BatteryState"](
                        header=header, voltage=voltage_v(t), temperature=25.0, current=-12.5,
                        charge=math.nan, capacity=math.nan, design_capacity=1.5, percentage=0.8,
                        power_supply_status=2, power_supply_health=1, power_supply_technology=3,
                        present=True, cell_voltage=np.zeros(0, dtype=np.float32),
                        cell_temperature=np.zeros(0, dtype=np.float32), location="",
                        serial_number="",
                    )  # fmt: skip
                elif key == "info":
                    armed, state = state_at(t)
                    msg = T["as2_msgs/msg/PlatformInfo"](
                        header=header, connected=True, armed=armed, offboard=armed,
                        status=T["as2_msgs/msg/PlatformStatus"](state=state),
                        current_control_mode=T["as2_msgs/msg/ControlMode"](
                            header=header, yaw_mode=1, control_mode=2, reference_frame=1
                        ),
                    )  # fmt: skip
                else:
                    pose = T["geometry_msgs/msg/Pose"](
                        position=T["geometry_msgs/msg/Point"](
                            x=0.0, y=0.0, z=1.0 if 2 <= t < 5 else 0.0
                        ),
                        orientation=quat(x=0.0, y=0.0, z=0.0, w=1.0),
                    )
                    msg = T["geometry_msgs/msg/PoseStamped"](header=header, pose=pose)
                # received 2 ms after the stamp
                events.append((ns + 2_000_000, key, ts.serialize_cdr(msg, topics[key][1])))
        for bag_ns, key, data in sorted(events, key=lambda e: (e[0], e[1])):
            writer.write(conns[key], bag_ns, data)
    return out


FIXTURE_BAGS = {"as2_hover_sim_sqlite3": "sqlite3", "as2_hover_sim_mcap": "mcap"}


def write_fixtures(directory: str | Path) -> list[Path]:
    """(Re)generate the project's Aerostack2 bag fixtures in ``directory``."""
    return [
        write_simulated_bag(Path(directory) / name, storage)
        for name, storage in FIXTURE_BAGS.items()
    ]
