"""``export_map``: one entry point for every export target (an encoding, the C header, the
firmware curves, the platform parameters). It sits above the modules that implement them, so
they never import each other in a cycle: ``encodings`` is the base (options, results, exact
rescaling), and ``c_header``, ``firmware``, ``platforms`` and ``encoding_yaml`` (the encoding
export, which uses ``platforms``' Crazyflie polynomial) build on it."""

from __future__ import annotations

from collections.abc import Callable

import thrustmap.fitting.export.firmware.ardupilot as ardupilot
import thrustmap.fitting.export.firmware.betaflight as betaflight
import thrustmap.fitting.export.firmware.px4 as px4
from thrustmap.core.errors import ConfigError
from thrustmap.core.units import SCALES
from thrustmap.fitting.export import c_header, platforms
from thrustmap.fitting.export.encoding_yaml import export_encoding
from thrustmap.fitting.export.encodings import ExportOptions, ExportResult, target_scale
from thrustmap.fitting.mapfile import ThrustMap
from thrustmap.fitting.names import TARGETS


def export_map(tmap: ThrustMap, target: str, options: ExportOptions | None = None) -> ExportResult:
    """Export ``tmap`` to ``target`` (an encoding name or a firmware target)."""
    opts = options or ExportOptions()
    if opts.rotors is not None and opts.rotors < 1:
        raise ConfigError(f"--rotors must be at least 1, got {opts.rotors}")
    if opts.mass_kg is not None and not opts.mass_kg > 0:
        raise ConfigError(f"--mass-kg must be positive, got {opts.mass_kg:g}")
    if target in SCALES:
        if opts.encoding is not None and opts.encoding != target:
            raise ConfigError(
                f"--encoding {opts.encoding} conflicts with --to {target}; give one of them"
            )
        return export_encoding(tmap, target_scale(target, opts.range_), opts)
    handlers: dict[str, Callable[[ThrustMap, ExportOptions], ExportResult]] = {
        "c-header": c_header.export_c_header,
        "aerostack2": platforms.export_aerostack2,
        "px4": px4.export_px4,
        "ardupilot": ardupilot.export_ardupilot,
        "betaflight": betaflight.export_betaflight,
    }
    handler = handlers.get(target)
    if handler is None:
        raise ConfigError(
            f"unknown export target '{target}'; expected one of: {', '.join(TARGETS)}"
        )
    return handler(tmap, opts)
