"""Recorded sweeps: the CI fixtures that replay a full bench run through the real runner.

``record(flavour, out_dir)`` runs a short stairs sweep on the simulator with both links tapped
by ``record://`` (the FC over MSP or MAVLink, and the Tyto stand), and keeps the Ds log it
produced. ``replay(flavour, fixture_dir, out_csv)`` runs the same plan through the same drivers
and runner on ``replay://`` transports, strictly: any message the code writes that the recording
cannot answer is an error (any byte, with ``match="bytes"``), and the Ds log must come out
identical.

Regenerate: ``python -m support.sweep_recordings fixtures/sweeps``.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import Any

import thrustmap.rig.devices.opening as opening
from thrustmap.core.clock import SimClock
from thrustmap.protocols.urlhandlers.protocol_record import record_url
from thrustmap.rig import plans
from thrustmap.rig.interlocks import Limits
from thrustmap.rig.run_types import RunConfig, RunResult
from thrustmap.rig.runner import record_sweep
from thrustmap.rig.sim import peers
from thrustmap.rig.sim.stand_peers import SIM_TYTO_CALIBRATION
from thrustmap.rig.stand.tyto import save_calibration

log = logging.getLogger(__name__)

#: flavour -> (FC URL on the simulator, driver kind)
FLAVOURS = {
    "msp": ("sim://betaflight?bench=fx&rotors=1&seed=7&protocol=PWM", "msp"),
    "px4": ("sim://px4?bench=fx&rotors=1&seed=7&motors=1", "px4"),
}
STAND_URL = "sim://tyto-1585?bench=fx&rotors=1&seed=7&drive_esc=0"


def plan() -> plans.Plan:
    return plans.stairs(10, 40, 10, dwell_s=1.5)


def _port_of(device: object) -> Any:
    link = getattr(device, "link", None)
    return getattr(device, "port", None) or getattr(link, "port", None)


def _run(
    fc_url: str,
    stand_url: str,
    kind: str,
    clock: SimClock,
    out_csv: Path,
    calibration: Path | None = None,
) -> tuple[RunResult, list[Any]]:
    stand = opening.open_stand(
        stand_url,
        clock,
        kind="tyto-1585",
        calibration=None if calibration is None else str(calibration),
    )
    with stand:
        fc = opening.open_throttle_output(fc_url, clock, kind=kind)
        with fc:
            result = record_sweep(
                plan(),
                fc,
                stand,
                str(out_csv),
                clock,
                limits=Limits(max_current_a=120),
                config=RunConfig(),
            )
    return result, [_port_of(fc), _port_of(stand)]


def calibration_path(folder: Path) -> Path:
    return folder / "tyto_calibration.json"


def paths(flavour: str, folder: Path) -> tuple[Path, Path, Path]:
    return (
        folder / f"{flavour}_fc.jsonl",
        folder / f"{flavour}_stand.jsonl",
        folder / f"{flavour}_run.csv",
    )


def record(flavour: str, out_dir: Path) -> RunResult:
    fc_sim, kind = FLAVOURS[flavour]
    fc_log, stand_log, run_csv = paths(flavour, out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    # Regenerating replaces the fixtures on purpose (the Ds writer never overwrites a recording).
    for old in (fc_log, stand_log, run_csv, run_csv.with_suffix(".meta.json")):
        old.unlink(missing_ok=True)
    save_calibration(
        SIM_TYTO_CALIBRATION, calibration_path(out_dir)
    )  # what a real unit's file would say
    peers.reset_benches()
    result, _ = _run(
        record_url(fc_sim, str(fc_log)),
        record_url(STAND_URL, str(stand_log)),
        kind,
        SimClock(),
        run_csv,
    )
    return result


def replay(
    flavour: str, fixture_dir: Path, out_csv: Path, *, match: str = "auto"
) -> tuple[RunResult, list[Any]]:
    """Replay strictly; returns the run and the two replay ports (``.report()``, ``.assert_consumed()``).

    ``match``: the FC link's replay mode (``auto`` is by message; ``bytes`` byte for byte)."""
    _, kind = FLAVOURS[flavour]
    fc_log, stand_log, _ = paths(flavour, fixture_dir)
    return _run(
        f"replay://{fc_log}?match={match}",
        f"replay://{stand_log}",
        kind,
        SimClock(),
        out_csv,
        calibration_path(fixture_dir),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("out_dir", type=Path)
    args = parser.parse_args()
    for flavour in FLAVOURS:
        result = record(flavour, args.out_dir)
        print(f"{flavour}: {result.status}, {result.samples} samples")  # noqa: T201 - a dev tool


if __name__ == "__main__":
    main()
