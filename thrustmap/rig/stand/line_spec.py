"""A user's own line stand, described in JSON: ``load_line_spec(path)`` reads the file,
``line_spec_from_dict`` checks and builds a ``LineStandSpec`` (starting from a preset with
``extends``), ``line_spec_to_dict`` writes one back. Errors name the file, the key and, where
it can, the line. The driver reading the stand (``rig.stand.line``) takes the spec this builds.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

from thrustmap.core.errors import ConfigError, DataFormatError
from thrustmap.core.jsonfile import load_json
from thrustmap.core.units import scale as lookup_scale
from thrustmap.protocols.stands.line import FIELDS, Column, LineStandSpec
from thrustmap.protocols.stands.line_presets import preset

SPEC_KEYS = {
    "format",
    "extends",
    "name",
    "description",
    "columns",
    "delimiter",
    "comment_prefix",
    "header_prefix",
    "header_names",
    "throttle_scale",
    "throttle_command",
    "stop_command",
    "keepalive",
    "keepalive_interval_s",
    "watchdog_s",
    "baudrate",
    "command_vars",
    "load_cell",
    "source",
    "verified",
    "drives_esc",
    "sequence_start",
    "sequence_end",
    "reset_stops",
    "line_patterns",
    "raw_counts",
    "row_separator",
    "sequence_levels",
    "sequence_settle_s",
    "sequence_rows",
    "sequence_row_period_s",
    "boot_s",
    "data_match",
    "cell_match",
    "watchdog_match",
    "error_match",
    "throttle_levels",
    "stop_confirm",
    "stop_time_s",
}
SPEC_FORMAT = "thrustmap-line-stand"
COLUMN_KEYS = {"index", "name", "scale", "offset", "modulo"}
LOAD_CELL_KEYS = {"field", "tare", "si_per_count"}


class _SpecReader:
    def __init__(self, source: str | None, text: str | None) -> None:
        self.source = source
        self.text = text

    def line_of(self, key: str) -> int | None:
        """The line of the first ``"key"`` in the file text (best effort)."""
        if not self.text or not key:
            return None
        leaf = key.rsplit(".", 1)[-1]
        at = self.text.find(f'"{leaf}"')
        return None if at < 0 else self.text.count("\n", 0, at) + 1

    def error(self, key: str, message: str) -> ConfigError:
        where = f"key '{key}': " if key else ""
        return ConfigError(where + message, file=self.source, line=self.line_of(key))

    def string(self, data: Mapping[str, Any], key: str, path: str, *, null: bool = False) -> Any:
        value = data[key]
        if value is None and null:
            return None
        if not isinstance(value, str):
            want = "a string or null" if null else "a string"
            raise self.error(path, f"expected {want}, got {value!r}")
        return value

    def number(
        self,
        data: Mapping[str, Any],
        key: str,
        path: str,
        *,
        null: bool = False,
        positive: bool = False,
    ) -> Any:
        value = data[key]
        if value is None and null:
            return None
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(path, f"expected a number, got {value!r}")
        if not math.isfinite(value) or (positive and value <= 0):
            raise self.error(path, f"expected a {'positive' if positive else 'finite'} number")
        return float(value)

    def unknown(self, data: Mapping[str, Any], known: set[str], prefix: str) -> None:
        extra = sorted(set(data) - known)
        if extra:
            raise self.error(
                prefix + extra[0], f"unknown key; expected some of {', '.join(sorted(known))}"
            )

    def column(self, field_name: str, data: Any) -> Column:
        path = f"columns.{field_name}"
        if not isinstance(data, dict):
            raise self.error(path, 'expected an object like {"index": 2, "scale": 0.001}')
        self.unknown(data, COLUMN_KEYS, path + ".")
        index = data.get("index")
        if index is not None and (
            isinstance(index, bool) or not isinstance(index, int) or index < 0
        ):
            raise self.error(path + ".index", f"expected a 0-based column number, got {index!r}")
        name = None if data.get("name") is None else self.string(data, "name", path + ".name")
        if (index is None) == (name is None):
            raise self.error(path, "expected exactly one of 'index' (0-based) or 'name'")
        scale = 1.0 if "scale" not in data else self.number(data, "scale", path + ".scale")
        if scale == 0:
            raise self.error(path + ".scale", "expected a non-zero number")
        offset = 0.0 if "offset" not in data else self.number(data, "offset", path + ".offset")
        modulo = data.get("modulo")
        if modulo is not None and (
            isinstance(modulo, bool) or not isinstance(modulo, int) or modulo < 2
        ):
            raise self.error(path + ".modulo", f"expected an integer >= 2, got {modulo!r}")
        return Column(index=index, name=name, scale=scale, offset=offset, modulo=modulo)


def _firmware_keys(r: _SpecReader, data: Mapping[str, Any]) -> dict[str, Any]:
    """The keys that describe a stand's firmware: its source, how it was checked, whether it
    drives the ESC, its own sequence, its reset, the lines probe knows it by, raw columns."""
    out: dict[str, Any] = {}
    for key in ("source", "verified"):
        if key in data:
            out[key] = r.string(data, key, key)
    for key in ("sequence_start", "sequence_end", "row_separator"):
        if key in data:
            out[key] = r.string(data, key, key, null=True)
    for key in ("drives_esc", "reset_stops"):
        if key in data:
            if not isinstance(data[key], bool):
                raise r.error(key, f"expected true or false, got {data[key]!r}")
            out[key] = data[key]
    for key in ("line_patterns", "raw_counts"):
        if key in data:
            items = data[key]
            if not isinstance(items, list) or not all(isinstance(n, str) for n in items):
                raise r.error(key, "expected a list of strings")
            out[key] = tuple(items)
    for key in ("sequence_settle_s", "sequence_row_period_s", "boot_s"):
        if key in data:
            out[key] = r.number(data, key, key)
            if out[key] < 0:
                raise r.error(key, "expected seconds >= 0")
    if "sequence_rows" in data:
        rows = data["sequence_rows"]
        if isinstance(rows, bool) or not isinstance(rows, int) or rows < 0:
            raise r.error("sequence_rows", f"expected a count >= 0, got {rows!r}")
        out["sequence_rows"] = rows
    if "sequence_levels" in data:
        levels = data["sequence_levels"]
        if not isinstance(levels, list) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in levels
        ):
            raise r.error("sequence_levels", "expected a list of throttle values")
        out["sequence_levels"] = tuple(float(v) for v in levels)
    return out


def line_spec_from_dict(
    data: Any, source: str | None = None, *, text: str | None = None
) -> LineStandSpec:
    """Build a ``LineStandSpec`` from a JSON object.

    Keys (all optional except where noted): ``extends`` (a preset name to start from),
    ``name`` and ``columns`` (required without ``extends``; ``columns`` maps a field among
    ``time_s, throttle, thrust_n, torque_nm, voltage_v, current_a, rpm`` to ``{"index": n}``
    (0-based) or ``{"name": "thrust_mN"}`` plus optional ``scale``/``offset``, with
    ``si = raw * scale + offset``; with ``extends`` the given columns replace the preset's,
    ``null`` removes one), ``delimiter`` (null: whitespace), ``comment_prefix``,
    ``header_prefix`` (null: no header), ``header_names``, ``throttle_scale`` (pwm, percent,
    ...), ``throttle_command``/``stop_command``/``keepalive`` (str.format templates with
    ``{us}``, ``{pct}``, ``{fraction}``, ``{native}``), ``keepalive_interval_s``,
    ``watchdog_s``, ``baudrate``, ``command_vars``, ``description`` and ``load_cell``
    (``{"field": "thrust_n", "tare": counts, "si_per_count": n}``) for a raw load cell.
    """
    r = _SpecReader(source, text)
    if not isinstance(data, dict):
        raise r.error("", "expected a JSON object at the top level")
    r.unknown(data, SPEC_KEYS, "")
    if "format" in data and data["format"] != SPEC_FORMAT:
        raise r.error("format", f'expected "{SPEC_FORMAT}", got {data["format"]!r}')
    base: LineStandSpec | None = None
    if data.get("extends") is not None:
        name = r.string(data, "extends", "extends")
        try:
            base = preset(name)
        except ConfigError as exc:
            raise r.error("extends", exc.message) from None
    elif "name" not in data or "columns" not in data:
        missing = "name" if "name" not in data else "columns"
        raise r.error(missing, "required (or 'extends' naming a preset to start from)")

    kwargs: dict[str, Any] = {}
    for key in ("name", "description", "comment_prefix", "throttle_scale"):
        if key in data:
            kwargs[key] = r.string(data, key, key)
    for key in ("delimiter", "header_prefix", "throttle_command", "stop_command", "keepalive"):
        if key in data:
            kwargs[key] = r.string(data, key, key, null=True)
    kwargs.update(_firmware_keys(r, data))
    if kwargs.get("delimiter") == "":
        raise r.error("delimiter", "expected a non-empty string, or null for whitespace")
    if "keepalive_interval_s" in data:
        kwargs["keepalive_interval_s"] = r.number(
            data, "keepalive_interval_s", "keepalive_interval_s", positive=True
        )
    if "watchdog_s" in data:
        kwargs["watchdog_s"] = r.number(data, "watchdog_s", "watchdog_s", null=True, positive=True)
    if "baudrate" in data:
        baud = data["baudrate"]
        if baud is not None and (isinstance(baud, bool) or not isinstance(baud, int) or baud <= 0):
            raise r.error("baudrate", f"expected a positive integer, got {baud!r}")
        kwargs["baudrate"] = baud
    if "header_names" in data:
        names = data["header_names"]
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise r.error("header_names", "expected a list of strings")
        kwargs["header_names"] = tuple(names)
    if "command_vars" in data:
        cvars = data["command_vars"]
        if not isinstance(cvars, dict):
            raise r.error("command_vars", "expected an object of template variables")
        kwargs["command_vars"] = dict(cvars)
    if "throttle_scale" in kwargs:
        try:
            lookup_scale(kwargs["throttle_scale"])
        except ConfigError as exc:
            raise r.error("throttle_scale", exc.message) from None

    kwargs["columns"] = _columns(r, data, base)
    kwargs.update(_matching_keys(r, data))

    try:
        spec = replace(base, **kwargs) if base is not None else LineStandSpec(**kwargs)
    except ConfigError as exc:
        raise ConfigError(exc.message, file=source) from None

    if data.get("load_cell") is not None:
        cell = data["load_cell"]
        if not isinstance(cell, dict):
            raise r.error("load_cell", 'expected {"field": "thrust_n", "tare": ..., ...}')
        r.unknown(cell, LOAD_CELL_KEYS, "load_cell.")
        for key in ("tare", "si_per_count"):
            if key not in cell:
                raise r.error(f"load_cell.{key}", "required")
        field_name = cell.get("field", "thrust_n")
        if field_name not in spec.columns:
            raise r.error("load_cell.field", f"no column for field {field_name!r}")
        tare = r.number(cell, "tare", "load_cell.tare")
        per = r.number(cell, "si_per_count", "load_cell.si_per_count")
        if per == 0:
            raise r.error("load_cell.si_per_count", "expected a non-zero number")
        spec = spec.with_load_cell(field_name, tare, per)
    return spec


def _columns(
    r: _SpecReader, data: Mapping[str, Any], base: LineStandSpec | None
) -> dict[str, Column]:
    """The preset's columns (if it extends one) with the file's ``columns`` over them."""
    columns: dict[str, Column] = dict(base.columns) if base is not None else {}
    if "columns" in data:
        given = data["columns"]
        if not isinstance(given, dict):
            raise r.error("columns", "expected an object mapping fields to columns")
        for field_name, col in given.items():
            if field_name not in FIELDS:
                raise r.error(
                    f"columns.{field_name}", f"unknown field; expected some of {', '.join(FIELDS)}"
                )
            if col is None and base is not None:
                columns.pop(field_name, None)
            else:
                columns[field_name] = r.column(field_name, col)
    return columns


def _matching_keys(r: _SpecReader, data: Mapping[str, Any]) -> dict[str, Any]:
    """``data_match``, ``cell_match``, ``stop_confirm`` (regular expressions or null),
    ``watchdog_match``, ``error_match`` (regular expressions), ``stop_time_s`` (seconds) and
    ``throttle_levels`` (``[[percent, "command"], ...]``)."""
    out: dict[str, Any] = {}
    for key in ("data_match", "cell_match", "stop_confirm"):
        if key in data:
            out[key] = r.string(data, key, key, null=True)
    for key in ("watchdog_match", "error_match"):
        if key in data:
            out[key] = r.string(data, key, key)
    if "stop_time_s" in data:
        out["stop_time_s"] = r.number(data, "stop_time_s", "stop_time_s")
    if "throttle_levels" in data:
        levels = data["throttle_levels"]
        ok = isinstance(levels, list) and all(
            isinstance(lv, list)
            and len(lv) == 2
            and isinstance(lv[0], (int, float))
            and not isinstance(lv[0], bool)
            and isinstance(lv[1], str)
            for lv in levels
        )
        if not ok:
            raise r.error("throttle_levels", 'expected a list of [percent, "command"] pairs')
        out["throttle_levels"] = tuple((float(lv[0]), lv[1]) for lv in levels)
    return out


def load_line_spec(path: str | Path) -> LineStandSpec:
    """Read a line-stand description from a JSON file (see ``line_spec_from_dict``): bounded and
    strict (``thrustmap.core.jsonfile``); errors name the file, the key and its line."""
    source = str(path)
    try:
        data = load_json(path, what="line stand spec")
    except DataFormatError as exc:
        raise ConfigError(exc.message, file=source, line=exc.line) from None
    text = Path(path).read_text(encoding="utf-8-sig", errors="replace")  # for the keys' lines
    return line_spec_from_dict(data, source, text=text)


def line_spec_to_dict(spec: LineStandSpec) -> dict[str, Any]:
    """The JSON form of a spec (``load_line_spec`` reads it back to an equal spec)."""
    columns: dict[str, dict[str, Any]] = {}
    for key, col in spec.columns.items():
        entry: dict[str, Any] = {"index": col.index} if col.index is not None else {}
        if col.name is not None:
            entry["name"] = col.name
        entry["scale"] = col.scale
        entry["offset"] = col.offset
        if col.modulo is not None:
            entry["modulo"] = col.modulo
        columns[key] = entry
    return {
        "format": SPEC_FORMAT,
        "name": spec.name,
        "description": spec.description,
        "columns": columns,
        "delimiter": spec.delimiter,
        "comment_prefix": spec.comment_prefix,
        "header_prefix": spec.header_prefix,
        "header_names": list(spec.header_names),
        "throttle_scale": spec.throttle_scale,
        "throttle_command": spec.throttle_command,
        "stop_command": spec.stop_command,
        "keepalive": spec.keepalive,
        "keepalive_interval_s": spec.keepalive_interval_s,
        "watchdog_s": spec.watchdog_s,
        "baudrate": spec.baudrate,
        "command_vars": dict(spec.command_vars),
        "source": spec.source,
        "verified": spec.verified,
        "drives_esc": spec.drives_esc,
        "sequence_start": spec.sequence_start,
        "sequence_end": spec.sequence_end,
        "reset_stops": spec.reset_stops,
        "line_patterns": list(spec.line_patterns),
        "raw_counts": list(spec.raw_counts),
        "row_separator": spec.row_separator,
        "sequence_levels": list(spec.sequence_levels),
        "sequence_settle_s": spec.sequence_settle_s,
        "sequence_rows": spec.sequence_rows,
        "sequence_row_period_s": spec.sequence_row_period_s,
        "boot_s": spec.boot_s,
        "data_match": spec.data_match,
        "cell_match": spec.cell_match,
        "watchdog_match": spec.watchdog_match,
        "error_match": spec.error_match,
        "throttle_levels": [[pct, cmd] for pct, cmd in spec.throttle_levels],
        "stop_confirm": spec.stop_confirm,
        "stop_time_s": spec.stop_time_s,
    }
