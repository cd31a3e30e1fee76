"""Aerostack2 ROS 2 bags (sqlite3 .db3 or .mcap) -> :class:`FlightLog`, with the pure-Python
``rosbags`` package (optional extra ``thrustmap[rosbag]``; no ROS install needed).

Topics, under each drone namespace (found automatically, or given with ``namespace=``):

| topic suffix | type | gives |
|---|---|---|
| ``actuator_command/thrust`` | as2_msgs/msg/Thrust | ``thrust_cmd_n`` (collective N), ``thrust_cmd_norm`` |
| ``sensor_measurements/imu`` | sensor_msgs/msg/Imu | ``accel_up_mps2`` = +linear_acceleration.z (FLU) |
| ``sensor_measurements/battery`` | sensor_msgs/msg/BatteryState | ``voltage_v``, current |
| ``platform/info`` | as2_msgs/msg/PlatformInfo | ``armed``; ``landed`` = status.state != FLYING (3) |
| ``self_localization/pose`` | geometry_msgs/msg/PoseStamped | extras ``position_z_m`` |

Message definitions embedded in the bag win; otherwise the as2_msgs definitions below (from the
aerostack2 repository, as2_msgs/msg/*.msg) are registered on top of ROS 2 Humble's types. A
bag recorded with another as2_msgs version whose PlatformInfo tail differs still gives armed and
state: those fields sit at the front of the message and are decoded directly when needed.

Times: header stamps when every used topic has them, else the bag's receive times; seconds from
the earliest sample.
"""

from __future__ import annotations

import logging
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from thrustmap.core.errors import DataFormatError
from thrustmap.flightlogs.series import FlightLog, Signal

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
EXTRA_HINT = "pip install 'thrustmap[rosbag]' (the pure-Python 'rosbags' package)"

#: as2_msgs definitions (aerostack2/as2_msgs/msg), registered when a bag carries none.
AS2_MSG_DEFS: dict[str, str] = {
    "as2_msgs/msg/Thrust": ("std_msgs/Header header\nfloat32 thrust\nfloat32 thrust_normalized\n"),
    "as2_msgs/msg/PlatformStatus": (
        "int8 EMERGENCY=-1\nint8 DISARMED=0\nint8 LANDED=1\nint8 TAKING_OFF=2\n"
        "int8 FLYING=3\nint8 LANDING=4\nint8 state\n"
    ),
    "as2_msgs/msg/ControlMode": (
        "std_msgs/Header header\n"
        "int8 NONE=0\nint8 YAW_ANGLE=1\nint8 YAW_SPEED=2\nint8 yaw_mode\n"
        "int8 UNSET=0\nint8 HOVER=1\nint8 POSITION=2\nint8 SPEED=3\nint8 SPEED_IN_A_PLANE=4\n"
        "int8 ATTITUDE=5\nint8 ACRO=6\nint8 TRAJECTORY=7\nint8 ACEL=8\nint8 control_mode\n"
        "int8 UNDEFINED_FRAME=0\nint8 LOCAL_ENU_FRAME=1\nint8 BODY_FLU_FRAME=2\n"
        "int8 GLOBAL_LAT_LONG_ASML=3\nint8 reference_frame\n"
    ),
    "as2_msgs/msg/PlatformInfo": (
        "std_msgs/Header header\nbool connected\nbool armed\nbool offboard\n"
        "as2_msgs/PlatformStatus status\nas2_msgs/ControlMode current_control_mode\n"
    ),
}
PLATFORM_FLYING = 3

TOPIC_THRUST = "actuator_command/thrust"
TOPIC_IMU = "sensor_measurements/imu"
TOPIC_BATTERY = "sensor_measurements/battery"
TOPIC_INFO = "platform/info"
TOPIC_POSE = "self_localization/pose"
KNOWN_SUFFIXES = (TOPIC_THRUST, TOPIC_IMU, TOPIC_BATTERY, TOPIC_INFO, TOPIC_POSE)


def sniff(path: Path, head: bytes) -> bool:
    """A rosbag2 directory (metadata.yaml), an .mcap file, or a rosbag2 sqlite3 .db3 file."""
    if path.is_dir():
        meta = path / "metadata.yaml"
        if not meta.is_file():
            return False
        text = meta.read_text(errors="replace")[:4096]
        return "rosbag2_bagfile_information" in text
    if head.startswith(b"\x89MCAP0\r\n"):
        return True
    return head.startswith(b"SQLite format 3\x00") and path.suffix.lower() == ".db3"


def _rosbags() -> Any:
    try:
        import rosbags.highlevel
        import rosbags.typesys
    except ImportError:
        raise DataFormatError(
            f"reading ROS 2 bags needs the optional extra: {EXTRA_HINT}"
        ) from None
    return rosbags


def as2_typestore() -> Any:
    """ROS 2 Humble's message types plus the as2_msgs ones."""
    rb = _rosbags()
    ts = rb.typesys.get_typestore(rb.typesys.Stores.ROS2_HUMBLE)
    types: dict[str, Any] = {}
    for name, text in AS2_MSG_DEFS.items():
        types.update(rb.typesys.get_types_from_msg(text, name))
    ts.register(types)
    return ts


@dataclass
class _Series:
    stamp_ns: list[int] = field(default_factory=list)
    bag_ns: list[int] = field(default_factory=list)
    rows: list[tuple[float, ...]] = field(default_factory=list)
    topic: str = ""


def _stamp_ns(msg: Any) -> int:
    header = getattr(msg, "header", None)
    if header is None:
        return 0
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def platform_info_prefix(raw: bytes) -> tuple[int, float, float]:
    """(stamp ns, armed, state) from a CDR PlatformInfo, reading only its leading fields."""
    little = raw[1] == 1
    e = "<" if little else ">"
    sec, nsec, slen = struct.unpack_from(e + "iII", raw, 4)
    p = 4 + 12 + slen  # encapsulation + stamp + string length + bytes (incl. NUL)
    connected, armed, offboard, state = struct.unpack_from("BBBb", raw, p)
    return sec * 1_000_000_000 + nsec, float(armed), float(state)


def _storage(path: Path) -> str:
    files = [path] if path.is_file() else sorted(path.iterdir())
    for f in files:
        if f.suffix in (".mcap", ".db3"):
            return "mcap" if f.suffix == ".mcap" else "sqlite3"
    return "unknown"


def _topics_by_namespace(topics: list[str]) -> dict[str, dict[str, str]]:
    found: dict[str, dict[str, str]] = {}
    for topic in topics:
        for suffix in KNOWN_SUFFIXES:
            if topic.endswith("/" + suffix) or topic == suffix:
                ns = topic[: len(topic) - len(suffix)].rstrip("/")
                found.setdefault(ns, {})[suffix] = topic
    return found


def read(
    path: Path | str,
    *,
    namespace: str | None = None,
    use_header_stamps: bool | None = None,
    **_options: Any,
) -> list[FlightLog]:
    """One :class:`FlightLog` per drone namespace in the bag (or the one ``namespace`` names)."""
    rb = _rosbags()
    p = Path(path)
    if not p.exists():
        raise DataFormatError("ROS 2 bag not found", file=str(p))
    try:
        reader = rb.highlevel.AnyReader([p], default_typestore=as2_typestore())
        reader.open()
    except Exception as exc:  # rosbags raises several unrelated types for unreadable bags
        reason = " ".join(str(exc).split())  # rosbags' messages run to 30 lines (YAML dumps)
        reason = reason if len(reason) <= 160 else reason[:160] + "..."
        raise DataFormatError(
            f"cannot open ROS 2 bag: {type(exc).__name__}: {reason}", file=str(p)
        ) from None
    try:
        conns = reader.connections
        by_ns = _topics_by_namespace(sorted({c.topic for c in conns}))
        if namespace is not None:
            ns_key = "/" + namespace.strip("/") if namespace.strip("/") else ""
            if ns_key not in by_ns:
                raise DataFormatError(
                    f"namespace '{namespace}' has no Aerostack2 topics; found: "
                    + (", ".join(repr(k or "/") for k in by_ns) or "none"),
                    file=str(p),
                )
            by_ns = {ns_key: by_ns[ns_key]}
        if not by_ns:
            raise DataFormatError(
                "no Aerostack2 topics (…/"
                + ", …/".join(KNOWN_SUFFIXES)
                + ") in the bag; topics: "
                + ", ".join(sorted({c.topic for c in conns})),
                file=str(p),
            )
        flights = [
            _read_namespace(reader, str(p), ns, topics, i, use_header_stamps)
            for i, (ns, topics) in enumerate(sorted(by_ns.items()))
        ]
    finally:
        reader.close()
    return flights


def _read_namespace(
    reader: Any,
    path: str,
    ns: str,
    topics: dict[str, str],
    index: int,
    use_header_stamps: bool | None,
) -> FlightLog:
    wanted = {topic: suffix for suffix, topic in topics.items()}
    conns = [c for c in reader.connections if c.topic in wanted]
    series: dict[str, _Series] = {s: _Series(topic=t) for s, t in topics.items()}
    warnings: list[str] = []
    failed: dict[str, int] = {}
    for conn, bag_ns, raw in reader.messages(connections=conns):
        suffix = wanted[conn.topic]
        s = series[suffix]
        try:
            msg = reader.deserialize(raw, conn.msgtype)
        except Exception:
            if suffix == TOPIC_INFO:
                try:
                    stamp, armed_f, state_f = platform_info_prefix(bytes(raw))
                except struct.error:
                    failed[conn.topic] = failed.get(conn.topic, 0) + 1
                    continue
                s.stamp_ns.append(stamp)
                s.bag_ns.append(bag_ns)
                s.rows.append((armed_f, state_f))
                continue
            failed[conn.topic] = failed.get(conn.topic, 0) + 1
            continue
        s.stamp_ns.append(_stamp_ns(msg))
        s.bag_ns.append(int(bag_ns))
        if suffix == TOPIC_THRUST:
            s.rows.append((float(msg.thrust), float(msg.thrust_normalized)))
        elif suffix == TOPIC_IMU:
            a = msg.linear_acceleration
            s.rows.append((float(a.x), float(a.y), float(a.z)))
        elif suffix == TOPIC_BATTERY:
            s.rows.append((float(msg.voltage), float(msg.current)))
        elif suffix == TOPIC_INFO:
            s.rows.append((float(msg.armed), float(msg.status.state)))
        else:
            s.rows.append((float(msg.pose.position.z),))
    for topic, count in failed.items():
        warnings.append(f"{count} message(s) on {topic} could not be decoded and were skipped")

    used = [s for s in series.values() if s.rows]
    if not used:
        raise DataFormatError(
            f"namespace '{ns or '/'}' has Aerostack2 topics but no messages", file=path
        )
    if use_header_stamps is None:
        use_header_stamps = all(min(s.stamp_ns) > 0 for s in used)
    stamps = {k: np.array(s.stamp_ns if use_header_stamps else s.bag_ns, dtype=np.int64)
              for k, s in series.items() if s.rows}  # fmt: skip
    t0 = min(int(v.min()) for v in stamps.values())

    fl = FlightLog(path=path, format="rosbag", index=index, warnings=warnings)

    def signal(suffix: str, col: int, unit: str, origin: str) -> Signal | None:
        if suffix not in stamps:
            return None
        t = (stamps[suffix] - t0) * 1e-9
        v = np.array([r[col] for r in series[suffix].rows], dtype=float)
        order = np.argsort(t, kind="stable")
        t, v = t[order], v[order]
        keep = np.isfinite(v) & np.append(True, np.diff(t) > 0)
        if not keep.any():
            return None
        dropped = int((~keep).sum())
        if dropped:
            warnings.append(
                f"{series[suffix].topic}: {dropped} sample(s) with NaN or repeated time dropped"
            )
        return Signal(t[keep], v[keep], unit, f"{series[suffix].topic}.{origin}")

    fl.thrust_cmd_n = signal(TOPIC_THRUST, 0, "N", "thrust (collective)")
    norm = signal(TOPIC_THRUST, 1, "1", "thrust_normalized")
    fl.thrust_cmd_norm = norm if norm is not None and np.any(norm.values != 0) else None
    fl.accel_up_mps2 = signal(TOPIC_IMU, 2, "m/s^2", "linear_acceleration.z (FLU, +up)")
    for col, name in ((0, "accel_x_mps2"), (1, "accel_y_mps2")):
        sig = signal(TOPIC_IMU, col, "m/s^2", f"linear_acceleration.{'xy'[col]}")
        if sig is not None:
            fl.extras[name] = sig
    fl.voltage_v = signal(TOPIC_BATTERY, 0, "V", "voltage")
    current = signal(TOPIC_BATTERY, 1, "A", "current")
    if current is not None:
        fl.extras["current_a"] = current
    fl.armed = signal(TOPIC_INFO, 0, "bool", "armed")
    state = signal(TOPIC_INFO, 1, "state", "status.state")
    if state is not None:
        fl.extras["platform_state"] = state
        fl.landed = Signal(
            state.time_s,
            (state.values != PLATFORM_FLYING).astype(float),
            "bool",
            f"{state.origin} != FLYING (3)",
        )
    pose_z = signal(TOPIC_POSE, 0, "m", "pose.position.z")
    if pose_z is not None:
        fl.extras["position_z_m"] = pose_z
    for suffix in (TOPIC_THRUST, TOPIC_IMU, TOPIC_BATTERY, TOPIC_INFO):
        if suffix not in stamps:
            warnings.append(f"no {ns}/{suffix} messages")
    ends = [float((v.max() - t0) * 1e-9) for v in stamps.values()]
    fl.metadata.update(
        namespace=ns or "/",
        topics={suffix: series[suffix].topic for suffix in stamps},
        message_counts={series[k].topic: len(series[k].rows) for k in stamps},
        time_source="header.stamp" if use_header_stamps else "bag receive time",
        time_origin_ns=t0,
        duration_s=max(ends),
        storage=_storage(Path(path)),
    )
    return fl
