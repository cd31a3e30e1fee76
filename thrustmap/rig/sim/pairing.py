"""Two ``sim://`` URLs in one run form one simulated bench: the stand measures the motor the
simulated flight controller drives.

A simulated stand (``sim://tyto-1585``) drives its own ESC unless told ``drive_esc=0``, and each
peer names its bench (default ``default``). With a simulated FC as the throttle output, a stand
that still drove its ESC would hold the rotor at its own (zero) command and measure nothing, so
``pair_sim_urls`` puts the stand on the FC's bench with ``drive_esc=0`` unless the URLs already
say otherwise. ``apart=True`` (``--sim-apart``) does the opposite on purpose: the stand sits on a
bench of its own that nothing drives — the simulated thrown propeller the thrust-response
interlock is tested with.
"""

from __future__ import annotations

from urllib.parse import parse_qsl

from thrustmap.rig.devices.urls import innermost_url, url_scheme

#: simulated stands whose ESC output can be switched off (``drive_esc=0``)
_DRIVES_ESC = ("tyto-1585",)


def _sim_options(url: str) -> tuple[str, dict[str, str]] | None:
    """(peer name, options) of the ``sim://`` URL inside ``url`` (through ``record://``)."""
    inner = innermost_url(url)
    if url_scheme(inner) != "sim":
        return None
    rest = inner[len("sim://") :]
    name, _, query = rest.partition("?")
    return name.strip("/").lower(), dict(parse_qsl(query, keep_blank_values=True))


def _add(url: str, extra: dict[str, str]) -> str:
    """Append options to ``url``'s query; ``record://`` hands them on to its inner ``sim://``."""
    if not extra:
        return url
    query = "&".join(f"{k}={v}" for k, v in extra.items())
    return url + ("&" if "?" in url else "?") + query


def pair_sim_urls(stand_url: str, throttle_url: str | None, *, apart: bool = False) -> str:
    """The stand URL to open: unchanged unless both URLs are simulated (see module)."""
    if throttle_url is None:
        return stand_url
    stand, fc = _sim_options(stand_url), _sim_options(throttle_url)
    if stand is None or fc is None:
        return stand_url
    name, options = stand
    fc_bench = fc[1].get("bench", "default")
    extra: dict[str, str] = {}
    if apart:
        if options.get("bench", "default") == fc_bench:
            extra["bench"] = f"{fc_bench}-apart"
    elif "bench" not in options and fc_bench != "default":
        extra["bench"] = fc_bench
    if name in _DRIVES_ESC and "drive_esc" not in options:
        extra["drive_esc"] = "0"
    return _add(stand_url, extra)
