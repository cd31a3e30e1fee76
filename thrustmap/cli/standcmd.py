"""CLI: ``thrustmap stand calibrate`` (tare + a known mass -> the calibration a preset reads) and
``thrustmap stand run`` (a firmware's own sweep, read as a recording into a Ds log)."""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING, Any

import click

from thrustmap.cli.bench import limit_options_except
from thrustmap.cli.hardware import CLOCK_CHOICE
from thrustmap.cli.textwidth import echo
from thrustmap.core.errors import ConfigError, ThrustmapError
from thrustmap.rig.interlocks import Limits

#: the interlock rows that do not apply to a sweep the firmware runs itself: thrustmap sets no
#: level (ceiling, slew) and the FC's link and the thrust response belong to its own runs
NOT_FOR_A_FIRMWARE_SWEEP = (
    "max_throttle_pct",
    "max_slew_pct_s",
    "stale_data_s",
    "link_timeout_s",
    "min_thrust_by_pct",
)

if TYPE_CHECKING:
    from thrustmap.core.clock import Clock
    from thrustmap.rig.stand.line import LineStand


@click.group("stand")
def stand_group() -> None:
    """DIY line stands: calibrate the load cell, run the firmware's own sweep."""


def _open(
    url: str,
    clock: Clock,
    preset_name: str,
    baud: int | None,
    calibration: str | None,
    raw_field: str | None = None,
) -> LineStand:
    from thrustmap.protocols.stands.line_presets import preset
    from thrustmap.rig.devices.urls import open_port
    from thrustmap.rig.stand.line import LineStand
    from thrustmap.rig.stand.line_calibration import load_line_calibration, raw_spec

    spec = preset(preset_name)
    if raw_field is not None:
        spec = raw_spec(spec, raw_field)
    elif calibration is not None:
        spec = load_line_calibration(calibration).apply(spec, calibration)
    port = open_port(url, clock, baudrate=baud or spec.baudrate or 115200)
    return LineStand(port, clock, spec)


def _confirm(text: str, yes: bool) -> None:
    if not yes and not click.confirm(text, default=False):
        raise click.Abort()


def _wait_enter(text: str) -> None:
    click.prompt(text, default="", show_default=False, prompt_suffix=" ")


@stand_group.command("calibrate")
@click.argument("url")
@click.option("--line-preset", "preset_name", required=True, help="The stand's preset.")
@click.option("--mass-g", type=float, required=True, help="The known mass, grams.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False))
@click.option("--samples", type=click.IntRange(3, 10_000), default=50, show_default=True)
@click.option("--field", "field_name", default="thrust_n", show_default=True)
@click.option("--baud", type=int, default=None, help="Serial baud rate (default: the preset's).")
@click.option(
    "--motor-unplugged",
    is_flag=True,
    help="A stand that prints only during its own sweep (tiny-thrust-stand): run that sweep "
    "twice with the motor unplugged (or the propeller off) and read its rows.",
)
@click.option("--timeout", "timeout_s", type=float, default=120.0, show_default=True)
@click.option(
    "--settle",
    "settle_s",
    type=click.FloatRange(0.0, 60.0),
    default=2.5,
    show_default=True,
    help="Seconds of readings dropped after each step (a firmware's moving average: "
    "HX711_ADC's 16 conversions at 10/s take 1.6 s).",
)
@click.option("--clock", "clock_choice", type=CLOCK_CHOICE, default="auto", show_default=True)
def calibrate_cmd(
    url: str,
    preset_name: str,
    mass_g: float,
    output: str,
    samples: int,
    field_name: str,
    baud: int | None,
    motor_unplugged: bool,
    timeout_s: float,
    settle_s: float,
    clock_choice: str,
) -> None:
    """Tare the load cell at rest, then read it under a known mass pulling the way thrust
    does; write the calibration (`--calibration FILE` on probe, `--line-calibration` on
    sweep). Never overwrites a file."""
    from thrustmap.cli.hardware import make_clock
    from thrustmap.core.files import check_output_path
    from thrustmap.rig.stand.line_calibration import (
        calibration_from_counts,
        write_line_calibration,
    )

    check_output_path(output, what="calibration")
    clock = make_clock(clock_choice, [url])
    stand = _open(url, clock, preset_name, baud, None, raw_field=field_name)
    with stand:
        if stand.spec.sequence_start is not None and not motor_unplugged:
            raise ConfigError(
                f"'{stand.spec.name}' prints only during its own sweep, which spins the motor: "
                "unplug the motor (or take the propeller off) and pass --motor-unplugged"
            )
        _wait_enter("Nothing on the load cell (motor stopped). Press Enter to tare.")
        rest = _counts(stand, field_name, samples, timeout_s, settle_s)
        _wait_enter(f"Hang {mass_g:g} g so that it pulls the way thrust does. Press Enter.")
        loaded = _counts(stand, field_name, samples, timeout_s, settle_s)
    cal = calibration_from_counts(stand.spec, rest, loaded, mass_g / 1000.0, field_name)
    write_line_calibration(output, cal)
    echo(
        f"{output}: tare {cal.tare_counts:.1f} counts, {cal.counts_per_n:.2f} counts/N "
        f"({cal.counts_per_n * 0.00980665:.2f} counts/g), noise {cal.noise_counts:.1f} counts"
    )


def _counts(
    stand: LineStand, field_name: str, samples: int, timeout_s: float, settle_s: float
) -> list[float]:
    from thrustmap.rig.stand.line_runs import collect_values, run_sequence

    if stand.spec.sequence_start is None:
        stand.wait_for_data(timeout_s)  # a board that resets when its port opens boots first
        end = stand.clock.now_s() + settle_s
        while stand.clock.now_s() < end:
            stand.read_samples()  # dropped: the reading is still moving to the new load
            stand.clock.sleep_s(0.02)
        return collect_values(stand, field_name, samples, timeout_s)
    result = run_sequence(stand, timeout_s)
    values = [getattr(s, field_name) for s in result.samples]
    return [float(v) for v in values if v is not None]


@stand_group.command("run")
@click.argument("url")
@click.option("--line-preset", "preset_name", required=True, help="The stand's preset.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Ds log.")
@click.option("--calibration", type=click.Path(dir_okay=False), help="From stand calibrate.")
@click.option("--baud", type=int, default=None, help="Serial baud rate (default: the preset's).")
@click.option("--timeout", "timeout_s", type=float, default=120.0, show_default=True)
@click.option("-y", "--yes", is_flag=True, help="Do not ask whether the area is clear.")
@click.option("--clock", "clock_choice", type=CLOCK_CHOICE, default="auto", show_default=True)
@limit_options_except(*NOT_FOR_A_FIRMWARE_SWEEP)
def run_cmd(
    url: str,
    preset_name: str,
    output: str,
    calibration: str | None,
    baud: int | None,
    timeout_s: float,
    yes: bool,
    clock_choice: str,
    **limit_values: Any,
) -> None:
    """Start the firmware's own sweep and record it as a Ds log (the throttle from its rows).
    Ctrl-C, SIGTERM, a tripped limit (thrust, current, rpm, cell voltage), a stand silent for
    5 s or any error stops it (its stop command, or a board reset where it has none).

    \b
    Exit codes: 0 done, 1 failed (board reset), 2 refused or bad input,
      3 stop NOT verified (cut the motor's power), 130 interrupted (board reset)."""
    from thrustmap.cli.hardware import make_clock
    from thrustmap.core.files import check_output_path

    check_output_path(output, what="Ds log")
    clock = make_clock(clock_choice, [url])
    stand = _open(url, clock, preset_name, baud, calibration)
    if stand.spec.sequence_start is None:
        stand.close()
        raise ConfigError(f"'{stand.spec.name}' runs no sweep of its own: use thrustmap sweep")
    if not yes and not click.confirm(
        f"'{stand.spec.name}' will run its own sweep: propeller on, area clear?", default=False
    ):
        stand.close()
        raise click.Abort()
    limits = Limits.from_options(limit_values)
    code = _record_sequence(stand, (url, output, calibration), timeout_s, limits)
    if code:
        sys.exit(code)


def _record_sequence(
    stand: LineStand, where: tuple[str, str, str | None], timeout_s: float, limits: Limits
) -> int:
    """Run the sequence into a Ds log (``where``: the stand's URL, the log, the calibration);
    the exit code (``sweep``'s meanings)."""
    url, output, calibration = where
    from thrustmap.core.stand_recording import DsWriter
    from thrustmap.core.units import scale
    from thrustmap.rig.interfaces import StandSample
    from thrustmap.rig.session import exit_code
    from thrustmap.rig.sigterm import terminate_as_exception
    from thrustmap.rig.stand.line_runs import run_sequence

    spec = stand.spec
    meta = {"devices": {"stand": {"url": url, "preset": spec.name, "source": spec.source}},
            "plan": {"kind": "firmware-sequence"}, "rotors_on_esc": 1, "strategy": "SR",
            "motor": 0, "calibration": calibration}  # fmt: skip
    writer = DsWriter(output, scale(spec.throttle_scale), meta)
    steps: list[float] = []

    def write(sample: StandSample, throttle: float) -> None:
        if not steps or steps[-1] != throttle:
            steps.append(throttle)
        values = {k: getattr(sample, k) for k in ("thrust_n", "voltage_v", "current_a", "rpm")}
        writer.write(sample.time_s, throttle, {**values, "step": len(steps) - 1,
                                               "phase": "firmware"})  # fmt: skip

    outcome, reason = "aborted", ""
    try:
        with terminate_as_exception(), stand:
            run_sequence(stand, timeout_s, write, limits)
            outcome, reason = "completed", f"'{spec.sequence_end}' from the firmware"
    except KeyboardInterrupt as exc:
        outcome, reason = "interrupted", f"{type(exc).__name__} {exc}".strip()
    except ThrustmapError as exc:
        reason = str(exc)
    finally:
        confirmed = stand.stop_confirmation
        verified = outcome == "completed" or stand.reset_verified or bool(confirmed)
        how = (
            "its end line" if outcome == "completed"
            else "a DTR reset, then silence" if stand.reset_verified
            else f"its stop command, confirmed by its {confirmed}" if confirmed else ""
        )  # fmt: skip
        writer.finish("completed" if outcome == "completed" else "aborted", reason,
                      {"stop_verified": verified, "stop": how or "NOT verified"})  # fmt: skip
    stop = f"stop verified ({how})" if verified else "stop NOT verified: cut the motor's power"
    echo(f"{outcome}: {writer.rows} rows, {len(steps)} levels; {stop}; log {output}"
         + (f" ({reason})" if outcome != "completed" else ""))  # fmt: skip
    return exit_code(outcome, verified)
