"""What a sweep run is set up with (``RunConfig``), what it reports on every tick to the live
readout (``Status``, through the phases ``PHASES``) and what it returns (``RunResult``): the
vocabulary between the runner (``rig.runner``) and those who start or watch a run (the bench
session, bench scripts, the live panel). Plain values, no I/O.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from thrustmap.rig.interfaces import StandSample, Telemetry
from thrustmap.rig.interlocks import Reading, Trip


@dataclass(frozen=True)
class RunConfig:
    motor: int = 0  # 0-based motor on the load cell
    rotors_on_esc: int = 1  # 4: all four motors get the same command (MR strategy)
    tick_s: float = 0.02  # control loop period
    telemetry_period_s: float = 0.2
    keepalive_s: float = 0.5  # re-send the command at least this often
    settle_window_s: float = 0.6  # settle detection: thrust range over this window ...
    settle_band_n: float = 0.01  # ... trend below max(this, settle_rel × thrust) or its noise
    settle_rel: float = 0.003
    tare: bool = True
    stop_retry_s: float = 10.0  # keep re-sending the stop this long until it is verified
    spin_down_s: float = 1.0  # before taring: the load cell must be still this long ...
    spin_down_max_s: float = 10.0  # ... within this time, or the run is refused
    #: confirm the motors at rest before the run (stopping them if not)
    check_at_rest: bool = True
    #: extra fields for the Ds log's sidecar (e.g. ``{"simulated": True}``)
    sidecar: Mapping[str, Any] = field(default_factory=dict)


#: the phases a run goes through, in order (``Status.phase``)
PHASES = ("at-rest", "tare", "plan")


@dataclass
class Status:
    """What the live readout shows (passed to the monitor callback every tick).

    ``phase`` is ``at-rest`` (waiting for the rotor to be still), ``tare`` or ``plan``;
    ``elapsed_s`` counts the plan only (0 before it starts), so progress and ETA are the
    plan's, and ``wait_s`` is the time spent before it."""

    time_s: float
    elapsed_s: float
    plan_duration_s: float
    segment: int
    segments: int
    label: str
    throttle_pct: float
    throttle_native: float
    reading: Reading
    margins: dict[str, float]
    phase: str = "plan"
    wait_s: float = 0.0
    telemetry: Telemetry | None = None  # the output's latest (FC battery, ESC rpm)
    sample: StandSample | None = None  # the stand's latest sample (None without a stand)
    plan_note: str = ""  # an adaptive plan's state (worst interval, time left)


@dataclass
class RunResult:
    status: str  # "completed" | "aborted"
    reason: str
    samples: int
    duration_s: float
    stop_verified: bool
    stop_latency_s: float | None  # from the abort decision to the stop command (sim-timed)
    trip: Trip | None = None
    log_path: str = ""
    interrupted: bool = False  # aborted by Ctrl-C or SIGTERM
    wait_s: float = 0.0  # before the plan: waiting for the rotor to rest, taring

    @property
    def outcome(self) -> str:
        """``completed``, ``interrupted`` (Ctrl-C/SIGTERM) or ``aborted`` (anything else)."""
        if self.status == "completed":
            return "completed"
        return "interrupted" if self.interrupted else "aborted"
