"""Each stand-log format's reader, detected by its header: RCbenchmark/Tyto, Flight Stand,
Crazyflie system-id and thrustmap's own Ds log (``FORMATS``, tried in order)."""

from __future__ import annotations

import logging
import re
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from thrustmap.core import stand_recording
from thrustmap.core.errors import DataFormatError
from thrustmap.core.physical import (  # the physical ranges live in one place
    G0,
)
from thrustmap.core.units import SCALES
from thrustmap.fitting.dataset import SAMPLE_AND_HOLD, Dataset
from thrustmap.fitting.loaders.assemble import StandColumns, assemble, finish_dataset
from thrustmap.fitting.loaders.table import (
    Table,
    column_values,
    find_column,
    need_column,
    thrust_unit_factor,
)

log = logging.getLogger(__name__)


MU = "\u00b5"


def _rcbenchmark(table: Table) -> Dataset | None:
    th = find_column(table, rf"esc(?: signal)? \({MU}s\)")
    scale, meta = SCALES["pwm"], {}
    if th is None and (th := find_column(table, r"esc signal")) is not None:
        # the app in DShot mode writes the command without a unit: DShot 0..2047 (48 the first
        # throttle value; bhabas/sar_simulation's dshot600 step tests)
        scale = SCALES["dshot"]
        meta["assumed"] = "'ESC signal' without a unit: read as the DShot command (48..2047)"
    thrust = find_column(table, r"thrust \(([^)]*)\)")
    if th is None or thrust is None:
        return None
    volt = need_column(table, r"voltage \(v\)", "'Voltage (V)'", "RCbenchmark")
    factor = thrust_unit_factor(table, thrust[0], thrust[1].group(1))
    t = find_column(table, r"time \(s\)")
    cur = find_column(table, r"current \(a\)")
    rpm = find_column(table, r"motor electrical speed \(rpm\)") or find_column(
        table, r"motor optical speed \(rpm\)"
    )
    return assemble(
        table,
        "rcbenchmark" if t is not None else "rcbenchmark-resaved",
        scale,
        {
            "throttle": th[0],
            "thrust": thrust[0],
            "voltage": volt[0],
            "time": None if t is None else t[0],
            "current": None if cur is None else cur[0],
            "rpm": None if rpm is None else rpm[0],
        },
        factor,
        meta=meta,
    )


def _flight_stand(table: Table) -> Dataset | None:
    rx = re.compile(rf"(.+) - esc throttle \({MU}s\)")
    trains = [(i, m) for i, k in enumerate(table.keys) if (m := rx.fullmatch(k))]
    if not trains:
        return None
    th = trains[0]
    name = th[1].group(1)
    meta: dict[str, Any] = {"powertrain": name}
    if len({m.group(1) for _, m in trains}) > 1:
        others = ", ".join(repr(table.header[i]) for i, _ in trains[1:])
        meta["powertrain_note"] = f"several powertrains: loaded '{name}' only; ignored {others}"
        log.warning("%s: %s", table.path, meta["powertrain_note"])
    elif len(trains) > 1:
        find_column(table, rx.pattern)  # the same powertrain twice: the duplicated-header error
    prefix = re.escape(name)
    thrust = need_column(
        table, rf"{prefix} - force fz \(thrust\) \(([^)]*)\)", "'force Fz (thrust)'", "Flight Stand"
    )
    volt = need_column(table, rf"{prefix} - voltage \(v\)", "'voltage (V)'", "Flight Stand")
    factor = thrust_unit_factor(table, thrust[0], thrust[1].group(1))
    t = find_column(table, r"time \(s\)")
    cur = find_column(table, rf"{prefix} - current \(a\)")
    rpm = find_column(table, rf"{prefix} - rotation speed \(rpm\)")
    return assemble(
        table,
        "flight-stand",
        SCALES["pwm"],
        {
            "throttle": th[0],
            "thrust": thrust[0],
            "voltage": volt[0],
            "time": None if t is None else t[0],
            "current": None if cur is None else cur[0],
            "rpm": None if rpm is None else rpm[0],
        },
        factor,
        meta=meta,
    )


#: The Crazyflie system-id logger writes one row every 10 ms and no time column.
CRAZYFLIE_PERIOD_S = 0.01


def _crazyflie(table: Table) -> Dataset | None:
    w = find_column(table, r"weight\[g\]")
    pwm = find_column(table, r"pwm")
    vbat = find_column(table, r"vbat\[v\]")
    if w is None or pwm is None or vbat is None:
        return None
    cur = find_column(table, r"i\[a\]")
    rpms = [hit[0] for k in range(1, 5) if (hit := find_column(table, rf"rpm{k}")) is not None]
    ds = assemble(
        table,
        "crazyflie",
        SCALES["crazyflie"],
        {"throttle": pwm[0], "thrust": w[0], "voltage": vbat[0], "current": cur and cur[0]},
        # weight[g] is the TOTAL of four motors; the map is per rotor (current likewise).
        G0 / 1000.0 / 4.0,
        rotors_on_esc=4,
        current_factor=0.25,
        meta={
            "thrust_note": "weight[g] of 4 motors divided by 4; i[A] likewise",
            "time_note": f"no time column: one row every {CRAZYFLIE_PERIOD_S * 1000:g} ms",
            "thrust_sensor": SAMPLE_AND_HOLD,  # its load cell updates every ~10 rows and holds
        },
    )
    n_rows = len(ds)
    time_s = (ds.line - ds.line[0]).astype(float) * CRAZYFLIE_PERIOD_S
    rpm = None
    if rpms:
        by_row = dict(zip(table.lines, range(len(table.lines)), strict=True))
        rows = [by_row[int(n)] for n in ds.line]
        each = np.vstack([column_values(table, i, allow_empty=True)[rows] for i in rpms])
        count = np.isfinite(each).sum(axis=0)
        total = np.where(np.isfinite(each), each, 0.0).sum(axis=0)
        rpm = np.where(count > 0, total / np.maximum(count, 1), np.nan) if n_rows else None
        ds.meta["rpm_note"] = f"mean of {len(rpms)} motors' rpm"
    return replace(ds, time_s=time_s, rpm=rpm)


def _thrustmap_ds(table: Table) -> Dataset | None:
    """thrustmap's own Ds log: decoded by :mod:`thrustmap.core.stand_recording`, checked against its sidecar."""
    if not stand_recording.is_ds_header(table.keys):
        return None
    cols = stand_recording.parse(table.header, table.rows, table.lines, table.path)
    side = stand_recording.read_sidecar(table.path)
    side_name = stand_recording.sidecar_path(table.path).name
    column = f"throttle_{cols.throttle_unit}"
    info: dict[str, Any] = {}
    if side is not None:
        scale = side.throttle_scale
        if stand_recording.throttle_column(scale) != column:
            raise DataFormatError(
                f"sidecar {side_name} gives throttle scale '{scale.name}' in {scale.unit}, "
                f"but the log's column is '{column}'; expected them to agree",
                file=table.path,
            )
        info["outcome"] = {"status": side.status, "reason": side.reason}
        info["strategy"] = side.strategy
        if side.status == "running":
            info["partial"] = "the run never finished (process died?): log kept as recorded"
        elif side.status == "aborted":
            info["partial"] = f"run aborted: {side.reason}"
        if side.samples is not None and side.samples != len(table.rows):
            if len(table.rows) > side.samples:
                raise DataFormatError(
                    f"the log has {len(table.rows)} rows but its sidecar {side_name} recorded "
                    f"{side.samples} samples; expected the sidecar of this log",
                    file=table.path,
                )
            info["partial"] = (
                f"sidecar {side_name} recorded {side.samples} samples but the log has "
                f"{len(table.rows)} rows: the log was cut short; loaded what is left"
            )
        rotors = side.rotors_on_esc
    else:
        rotors = None
        defaults = {"us": SCALES["pwm"], "pct": SCALES["percent"]}
        if cols.throttle_unit not in defaults:
            raise DataFormatError(
                f"no sidecar {side_name}: it gives the throttle scale of '{column}'",
                file=table.path,
            )
        scale = defaults[cols.throttle_unit]
        if cols.throttle_unit == "us":
            log.warning("%s: no sidecar %s; assuming PWM 1000..2000 us", table.path, side_name)
            info["assumed"] = f"no sidecar: throttle scale PWM 1000..2000 us assumed for '{column}'"
    outside = np.flatnonzero(
        (cols.throttle_native < scale.lo - scale.span / 2)
        | (cols.throttle_native > scale.hi + scale.span / 2)
    )
    if outside.size:
        k = int(outside[0])
        raise DataFormatError(
            f"throttle {cols.throttle_native[k]:g} is far outside the scale '{scale.name}' "
            f"{scale.lo:g}..{scale.hi:g} {scale.unit}; expected values on that scale",
            file=table.path,
            line=int(cols.line[k]),
            column=column,
        )
    if "partial" in info:
        log.warning("%s: %s", table.path, info["partial"])
    stand = StandColumns(
        cols.throttle_native,
        cols.thrust_n,
        cols.voltage_v,
        time_s=cols.time_s,
        current_a=cols.current_a,
        rpm=cols.rpm,
        # steps as recorded; none recorded (a hand-made log): plateaus from the throttle
        step=None
        if cols.step is None or not (cols.step >= 0).any()
        else np.where(cols.stopping, -1, cols.step),
        settled=cols.settled,
    )
    return finish_dataset(table, "thrustmap", scale, stand, rotors_on_esc=rotors, meta=info)


#: name -> (description, reader). Tried in this order; a reader returns None when the header
#: is not its format, and raises DataFormatError when it is but something is wrong.
FORMATS: dict[str, tuple[str, Callable[[Table], Dataset | None]]] = {
    "thrustmap": (
        "thrustmap Ds log: time_s, throttle_<unit>, thrust_n, voltage_v + JSON sidecar",
        _thrustmap_ds,
    ),
    "rcbenchmark": (
        "RCbenchmark/Tyto app log: 'ESC signal (µs)' or 'ESC (µs)' ('ESC signal': DShot), 'Thrust (N|kgf|gf)', 'Voltage (V)'",
        _rcbenchmark,
    ),
    "flight-stand": (
        "Flight Stand export: '<powertrain> - ESC throttle (μs)', '... - force Fz (thrust) (N)', '... - voltage (V)'",
        _flight_stand,
    ),
    "crazyflie": ("Crazyflie system-id log: 'weight[g]', 'pwm', 'vbat[V]'", _crazyflie),
}
