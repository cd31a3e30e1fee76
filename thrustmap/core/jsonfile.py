"""Reading user-facing JSON files (maps, sidecars, stand specs, calibrations) with one error style.

:func:`load_json` reads a file with bounds (size, nesting depth), strict numbers (``NaN`` and
``Infinity`` are refused, as are numbers too large for a float) and UTF-8 checked, and raises
:class:`~thrustmap.core.errors.DataFormatError` naming the file (and line, where JSON says) for any
problem. :class:`Fields` then takes typed values out of an object and names the field path
(``calibration.load_cell.scale``) and what was expected when one is missing or of the wrong kind.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from thrustmap.core.errors import DataFormatError

MAX_JSON_BYTES = 64 * 1024 * 1024
MAX_JSON_DEPTH = 64


def _depth_ok(text: str, limit: int) -> bool:
    """Nesting depth of ``[``/``{`` outside strings, without recursion."""
    depth = 0
    in_string = False
    escaped = False
    for ch in text:
        if in_string:
            if escaped:
                escaped = False
            elif ch == "\\":
                escaped = True
            elif ch == '"':
                in_string = False
        elif ch == '"':
            in_string = True
        elif ch in "[{":
            depth += 1
            if depth > limit:
                return False
        elif ch in "]}":
            depth -= 1
    return True


def _refuse_constant(name: str) -> float:
    raise ValueError(f"{name} is not a number JSON allows")


def _parse_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"number {text[:40]} is too large")
    return value


def _parse_int(text: str) -> int:
    if len(text) > 30:
        raise ValueError(f"integer with {len(text)} digits is too large")
    return int(text)


def _not_json_but(text: str) -> str | None:
    """What a text given as JSON probably is instead: a CSV (a stand log or a Df given where
    a map is expected, `evaluate LOG MAP` for `evaluate MAP LOG`) or an export's text."""
    first = text.lstrip("\ufeff").split("\n", 1)[0].strip()
    if first.startswith("# thrustmap"):
        return "an export thrustmap wrote"
    if first.count(",") >= 2 and not first.startswith(("{", "[")):
        return "a CSV, e.g. a stand log or a Df"
    return None


def loads_json(text: str, *, source: str, max_depth: int = MAX_JSON_DEPTH) -> Any:
    """Parse JSON text; ``source`` names it in errors."""
    if not _depth_ok(text, max_depth):
        raise DataFormatError(f"JSON nested deeper than {max_depth} levels", file=source)
    try:
        return json.loads(
            text,
            parse_constant=_refuse_constant,
            parse_float=_parse_float,
            parse_int=_parse_int,
        )
    except json.JSONDecodeError as exc:
        what = _not_json_but(text)
        raise DataFormatError(
            f"not valid JSON: {exc.msg}" + (f" ({what}, not a JSON file)" if what else ""),
            file=source,
            line=exc.lineno,
        ) from None
    except ValueError as exc:
        raise DataFormatError(f"not valid JSON: {exc}", file=source) from None


def load_json(
    path: str | os.PathLike[str], *, max_bytes: int = MAX_JSON_BYTES, what: str = "JSON file"
) -> Any:
    """Read and parse a JSON file with bounds; every problem is a one-line DataFormatError."""
    p = Path(path)
    try:
        size = p.stat().st_size
        if size > max_bytes:
            raise DataFormatError(
                f"{what} is {size} bytes; expected at most {max_bytes}", file=str(p)
            )
        raw = p.read_bytes()
    except OSError as exc:
        raise DataFormatError(f"cannot read {what}: {exc.strerror or exc}", file=str(p)) from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise DataFormatError(f"{what} is not UTF-8 text (byte {exc.start})", file=str(p)) from None
    return loads_json(text, source=str(p))


class Fields:
    """Typed access to a JSON object's fields, with errors naming the field path.

    >>> f = Fields({"a": {"b": 2}}, source="x.json")
    >>> f.sub("a").number("b")
    2.0
    """

    def __init__(self, obj: Any, *, source: str, path: str = "") -> None:
        self.source = source
        self.path = path
        if not isinstance(obj, Mapping):
            raise self.error(f"expected an object, got {_kind(obj)}")
        self.obj: Mapping[str, Any] = obj

    def _name(self, key: str) -> str:
        return f"{self.path}.{key}" if self.path else key

    def error(self, message: str, key: str | None = None) -> DataFormatError:
        where = self._name(key) if key is not None else self.path
        prefix = f"field '{where}': " if where else ""
        return DataFormatError(prefix + message, file=self.source)

    def has(self, key: str) -> bool:
        return key in self.obj and self.obj[key] is not None

    def raw(self, key: str) -> Any:
        if key not in self.obj:
            raise self.error("missing", key)
        return self.obj[key]

    def sub(self, key: str) -> Fields:
        return Fields(self.raw(key), source=self.source, path=self._name(key))

    def number(
        self,
        key: str,
        default: float | None = None,
        *,
        minimum: float | None = None,
        maximum: float | None = None,
    ) -> float:
        if key not in self.obj or self.obj[key] is None:
            if default is None:
                raise self.error("missing; expected a number", key)
            return default
        value = self.obj[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(f"expected a number, got {_kind(value)}", key)
        out = float(value)
        if not math.isfinite(out):
            raise self.error("expected a finite number", key)
        if minimum is not None and out < minimum:
            raise self.error(f"expected at least {minimum:g}, got {out:g}", key)
        if maximum is not None and out > maximum:
            raise self.error(f"expected at most {maximum:g}, got {out:g}", key)
        return out

    def integer(
        self,
        key: str,
        default: int | None = None,
        *,
        minimum: int | None = None,
        maximum: int | None = None,
    ) -> int:
        if key not in self.obj or self.obj[key] is None:
            if default is None:
                raise self.error("missing; expected an integer", key)
            return default
        value = self.obj[key]
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(f"expected an integer, got {_kind(value)}", key)
        if minimum is not None and value < minimum:
            raise self.error(f"expected at least {minimum}, got {value}", key)
        if maximum is not None and value > maximum:
            raise self.error(f"expected at most {maximum}, got {value}", key)
        return value

    def string(self, key: str, default: str | None = None, *, choices: tuple[str, ...] = ()) -> str:
        if key not in self.obj or self.obj[key] is None:
            if default is None:
                raise self.error("missing; expected a string", key)
            return default
        value = self.obj[key]
        if not isinstance(value, str):
            raise self.error(f"expected a string, got {_kind(value)}", key)
        if choices and value not in choices:
            raise self.error(f"expected one of {', '.join(choices)}, got '{value[:40]}'", key)
        return value

    def boolean(self, key: str, default: bool | None = None) -> bool:
        if key not in self.obj or self.obj[key] is None:
            if default is None:
                raise self.error("missing; expected true or false", key)
            return default
        value = self.obj[key]
        if not isinstance(value, bool):
            raise self.error(f"expected true or false, got {_kind(value)}", key)
        return value

    def numbers(self, key: str) -> list[float]:
        value = self.raw(key)
        if not isinstance(value, list):
            raise self.error(f"expected a list of numbers, got {_kind(value)}", key)
        out: list[float] = []
        for i, v in enumerate(value):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise self.error(f"item {i}: expected a finite number, got {_kind(v)}", key)
            out.append(float(v))
        return out


def _kind(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, (int, float)):
        return f"the number {value!r}"[:60]
    if isinstance(value, str):
        return f"the string '{value[:30]}'"
    if isinstance(value, list):
        return "a list"
    if isinstance(value, Mapping):
        return "an object"
    return type(value).__name__
