"""Every line-stand preset by name: the two in ``protocols.stands.line`` (the reference protocol
and the RP2040 whoop notes) and one module per DIY firmware in ``protocols.stands.presets``.

A firmware preset is a module ``thrustmap/protocols/stands/presets/<stand>.py`` defining
``PRESET: LineStandSpec`` (its ``source`` cites the firmware repository, commit, file and line)
and optionally ``ALIASES: tuple[str, ...]`` (older names that now mean it). Modules are found
on first use (``pkgutil``), so adding a stand is adding one file.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Mapping

from thrustmap.core.errors import ConfigError
from thrustmap.protocols.stands import presets as presets_package
from thrustmap.protocols.stands.line import PRESETS as BUILTIN
from thrustmap.protocols.stands.line import LineStandSpec

_loaded: dict[str, LineStandSpec] = {}
_aliases: dict[str, str] = {}


def _load() -> None:
    if _loaded:
        return
    found: dict[str, LineStandSpec] = dict(BUILTIN)
    aliases: dict[str, str] = {}
    for info in sorted(pkgutil.iter_modules(presets_package.__path__), key=lambda i: i.name):
        module = importlib.import_module(f"{presets_package.__name__}.{info.name}")
        spec = getattr(module, "PRESET", None)
        if not isinstance(spec, LineStandSpec):
            raise ConfigError(f"line stand preset module {info.name} defines no PRESET spec")
        if spec.name in found:
            raise ConfigError(f"two line stand presets are named '{spec.name}'")
        found[spec.name] = spec
        for alias in getattr(module, "ALIASES", ()):
            aliases[str(alias).lower()] = spec.name
    _aliases.update({a: n for a, n in aliases.items() if a not in found})
    _loaded.update(found)


def presets() -> Mapping[str, LineStandSpec]:
    """Every preset by its name (aliases not included)."""
    _load()
    return dict(_loaded)


def aliases() -> Mapping[str, str]:
    """Older preset names -> the preset they now mean."""
    _load()
    return dict(_aliases)


def preset(name: str) -> LineStandSpec:
    """The preset called ``name`` (or an alias of it); unknown names list the known ones."""
    _load()
    key = name.strip().lower()
    key = _aliases.get(key, key)
    try:
        return _loaded[key]
    except KeyError:
        raise ConfigError(
            f"unknown line stand preset '{name}'; expected one of: {', '.join(_loaded)}"
        ) from None


def identify(lines: list[str]) -> list[LineStandSpec]:
    """The presets whose ``line_patterns`` match every one of ``lines`` (complete lines a port
    printed unasked); more than one means the lines do not tell them apart."""
    return [spec for spec in presets().values() if spec.matches_lines(lines)]
