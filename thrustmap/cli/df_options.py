"""The Df filter options of ``flightlog extract``, ``fleet extract`` and ``gamma live``, made
from ``DfOptions`` (``thrustmap.fitting.df_options``): each option's flag, default, help and
unit come from its field, so a default is declared once.

A command takes ``@df_click_options(FIELDS)``: the option of each named field, passed to the
command under the field's name (``accel_tol_mps2``); they are the
keyword arguments of ``DfOptions`` (a command takes them as ``**df_values``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

import click

from thrustmap.fitting.df_options import OPTION_FIELDS

F = TypeVar("F", bound=Callable[..., Any])

#: what ``flightlog extract`` and ``fleet extract`` expose (every filter a user may tune)
EXTRACT_FIELDS = (
    "mass_kg",
    "rotors",
    "thrust_source",
    "rate_hz",
    "accel_tol_mps2",
    "tilt_max_deg",
    "settle_s",
    "min_height_m",
    "climb_max_mps",
)
#: what ``gamma live`` exposes (its mass is required: a live stream names none)
LIVE_FIELDS = ("mass_kg", "rotors", "rate_hz", "settle_s")

_TYPES: dict[str, type] = {"float": float, "float | None": float, "int": int, "int | None": int,
                           "str": str}  # fmt: skip


class DfOption(click.Option):
    """A click option made from a DfOptions field (tests tell the generated ones by this)."""


def _option(name: str, required: bool) -> Callable[[F], F]:
    f = OPTION_FIELDS[name]
    meta = f.metadata
    unit = f" [{meta['unit']}]" if meta["unit"] else ""
    kind: Any = click.Choice(meta["choices"]) if meta["choices"] else _TYPES[str(f.type)]
    given: dict[str, Any] = {"required": True} if required else {"default": f.default}
    return click.option(
        meta["option"],
        name,
        cls=DfOption,
        type=kind,
        show_default=not required and f.default is not None,
        help=meta["help"] + unit,
        **given,
    )


def df_click_options(names: tuple[str, ...], required: tuple[str, ...] = ()) -> Callable[[F], F]:
    """Add the click options of the DfOptions fields ``names`` (in that order) to a command,
    each passed under its field's name; those in ``required`` must be given."""
    unknown = (set(names) - set(OPTION_FIELDS)) | (set(required) - set(names))
    if unknown:
        raise ValueError(f"not DfOptions command-line fields: {sorted(unknown)}")

    def add(fn: F) -> F:
        for name in reversed(names):  # click lists the options bottom up
            fn = _option(name, name in required)(fn)
        return fn

    return add
