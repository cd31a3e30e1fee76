"""``thrustmap export``: a map in a throttle encoding, a C header, or firmware parameters."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import click

from thrustmap.cli.textwidth import echo
from thrustmap.core import physical
from thrustmap.core.errors import ConfigError
from thrustmap.core.units import SCALES, parse_range
from thrustmap.fitting.names import TARGETS

log = logging.getLogger(__name__)


def _name(given: str, names: tuple[str, ...], option: str, what: str) -> str:
    """A target or encoding name as typed (`PX4`, `ArduPilot`, `DShot600`): matched without case."""
    by_lower = {n.lower(): n for n in names}
    found = by_lower.get(given.strip().lower())
    if found is None:
        raise ConfigError(
            f"{option}: unknown {what} '{given}'; expected one of: {', '.join(names)}"
        )
    return found


@click.command("export")
@click.argument("map_file", metavar="MAP", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "--to",
    "target",
    required=True,
    metavar="TARGET",
    help="One of: " + ", ".join(TARGETS) + ".",
)
@click.option(
    "--range",
    "range_text",
    metavar="LO:HI",
    help="Endpoints of the output encoding in its own units (e.g. 1100:1940 for PWM µs).",
)
@click.option(
    "--encoding",
    metavar="NAME",
    help="Output encoding for c-header (default percent), aerostack2 (pwm), px4/ardupilot "
    "(pwm) and betaflight (dshot or pwm). One of: " + ", ".join(SCALES) + ".",
)
@click.option("--mass-kg", type=float, help="Vehicle mass, for hover parameters.")
@click.option("--rotors", type=int, help="Rotor count (default 4).")
@click.option(
    "--voltage-v",
    type=float,
    help="Reference voltage: where voltage-free curves are fitted and the 'full battery' "
    "voltage for PX4/ArduPilot scaling (default: top of the map's voltage box).",
)
@click.option(
    "--firmware",
    metavar="VERSION",
    help="Firmware version whose names, ranges and rules the export follows: betaflight "
    "4.5, 4.6 (2025.12) or 2026.6 (required); ardupilot 4.x; px4 1.12-1.13 or 1.14+ "
    "(default 1.14+).",
)
@click.option(
    "--spin-max",
    type=float,
    default=0.95,
    show_default=True,
    help="ArduPilot MOT_SPIN_MAX (fixed; it sets the scale of MOT_THST_EXPO).",
)
@click.option(
    "-o",
    "--output",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Write here instead of standard output.",
)
def export_cmd(
    map_file: Path,
    target: str,
    range_text: str | None,
    encoding: str | None,
    mass_kg: float | None,
    rotors: int | None,
    voltage_v: float | None,
    firmware: str | None,
    spin_max: float,
    output: Path | None,
) -> None:
    """Export MAP for a throttle encoding or a firmware."""
    target = _name(target, TARGETS, "--to", "target")
    if encoding is not None:
        encoding = _name(encoding, tuple(SCALES), "--encoding", "encoding")
    if not 0.0 < spin_max <= 1.0:
        raise ConfigError(f"--spin-max: expected a value in (0, 1], got {spin_max:g}")
    range_ = parse_range(range_text, "--range") if range_text is not None else None
    if voltage_v is not None:
        physical.battery_voltage_v(voltage_v, "--voltage-v")
    if mass_kg is not None:
        physical.positive(mass_kg, "--mass-kg", "kg")
    if rotors is not None and not 1 <= rotors <= 64:
        raise ConfigError(f"--rotors: expected 1..64 rotors, got {rotors}")
    from thrustmap.api import export, load_map

    plan = None
    if output is not None:
        from thrustmap.core.files import check_output_path

        plan = check_output_path(output, inputs=[map_file], what="export output")
    tmap = load_map(map_file)
    if mass_kg is not None and (why := tmap.hover_refusal(mass_kg, rotors or 4)) is not None:
        raise ConfigError(f"--mass-kg: {why}")
    result = export(
        tmap,
        target,
        range_=range_,
        encoding=encoding,
        mass_kg=mass_kg,
        rotors=rotors,
        voltage_v=voltage_v,
        firmware=firmware,
        spin_max=spin_max,
    )
    if output is None or plan is None:
        click.echo(result.text, nl=False)  # the file itself: never wrapped
        return
    from thrustmap.core.files import atomic_write_text

    atomic_write_text(output, result.text)
    summary = ", ".join(f"{k} {v:.3g}" for k, v in result.residual.items())
    replaced = "; replaced the previous file" if plan.replaced else ""
    echo(f"wrote {output} ({target}; residual {summary or 'n/a'}{replaced})", err=True)
    for line in _extrapolated_lines(result.values.get("map_values")):
        echo(line, err=True)


def _extrapolated_lines(values: Any) -> list[str]:
    """One line per written map value outside the supported region (the header lists them
    too): the user sees on the terminal what the file extrapolates."""
    if values is None:
        return []
    return [
        f"extrapolated: {v.name} {v.value:.4g} {v.unit}, {v.interval_text()}"
        for v in values.outside()
    ]
