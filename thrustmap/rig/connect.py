"""Open devices by URL: the factories ``thrustmap probe``, ``spin``, ``sweep`` and the bench
session build on. Each goes through the driver registry (``rig.devices``):

- ``open_throttle_output(url, clock, kind=...)``: an FC over MSP (Betaflight/INAV) or MAVLink
  (PX4/ArduPilot), or a stand's own ESC output (Tyto 1585, line stand).
- ``open_stand(url, clock, kind=...)``: a Tyto 1585 (needs its calibration file) or a line stand
  (a preset or a JSON spec file).
- ``stand_esc_output(stand)``: the ESC output of an open stand that drives its ESC.

Kinds are the registered drivers' (``msp``, ``mavlink``, ``tyto-1585``, ``line-stand``) or their
aliases (``betaflight``, ``inav``, ``px4``, ``ardupilot``: also the firmware hint; ``tyto``,
``line``). Everything here lives in ``rig.devices`` (the opening itself in
``rig.devices.opening``) and is re-exported for callers that know only this module; nothing in
``rig.devices`` imports this module.
"""

from __future__ import annotations

from thrustmap.rig.devices.builtin import line_spec_for
from thrustmap.rig.devices.detect import (
    PROBE_BAUDS,
    classify_bytes,
    detect_from_url,
    detect_kind,
    resolve,
    sniff,
)
from thrustmap.rig.devices.opening import (
    StandEscOutput,
    open_stand,
    open_throttle_output,
    stand_esc_output,
)
from thrustmap.rig.devices.ports import PortDescription, PortInfo, describe_port, list_ports
from thrustmap.rig.devices.probe import ProbeReport, StandSummary, probe_device, summarize_samples
from thrustmap.rig.devices.registry import (
    Detection,
    OpenRequest,
    driver,
    drivers,
    kind_aliases,
    kinds,
    normalize_kind,
)
from thrustmap.rig.devices.urls import (
    innermost_url,
    is_simulated,
    load_sim_peers,
    open_port,
    sim_peer,
    url_scheme,
)

__all__ = [
    "PROBE_BAUDS",
    "Detection",
    "OpenRequest",
    "PortDescription",
    "PortInfo",
    "ProbeReport",
    "StandEscOutput",
    "StandSummary",
    "classify_bytes",
    "describe_port",
    "detect_from_url",
    "detect_kind",
    "driver",
    "drivers",
    "innermost_url",
    "is_simulated",
    "kind_aliases",
    "kinds",
    "line_spec_for",
    "list_ports",
    "load_sim_peers",
    "normalize_kind",
    "open_port",
    "open_stand",
    "open_throttle_output",
    "probe_device",
    "resolve",
    "sim_peer",
    "sniff",
    "stand_esc_output",
    "summarize_samples",
    "url_scheme",
]
