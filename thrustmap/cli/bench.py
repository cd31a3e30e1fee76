"""CLI: sweep (a bench run with interlocks, recorded as a Ds log) and demo (the simulator)."""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import click

from thrustmap.clock import Clock, MonotonicClock, SimClock
from thrustmap.errors import ConfigError
from thrustmap.rig import plans
from thrustmap.rig.interlocks import Limits, check_plan
from thrustmap.rig.runner import RunConfig, Status, record_sweep
from thrustmap.rig.safety import terminate_as_exception


@click.command("demo")
@click.option(
    "-o",
    "--out",
    "out_dir",
    default="thrustmap-demo",
    show_default=True,
    type=click.Path(file_okay=False),
    help="Folder for the Ds logs and maps.",
)
@click.option("--seed", default=1, show_default=True, help="Simulator seed (noise).")
@click.option("-q", "--quiet", is_flag=True, help="Only the final comparison.")
def demo_cmd(out_dir: str, seed: int, quiet: bool) -> None:
    """Simulated SR and MR bench campaigns on the xNova 2207 / 6S preset, fitted and compared.

    No hardware: a simulated Betaflight FC and Tyto 1585 stand speak the real protocols to the
    real drivers and runner; the paper's four experiments are recorded, every model is fitted,
    and a Table-3-style comparison is printed (in-sample, held-out, and against the simulator's
    true map)."""
    from thrustmap.demo import report, run_demo

    start = time.perf_counter()
    results = run_demo(
        Path(out_dir), seed=seed, progress=None if quiet else (lambda m: click.echo(m, err=True))
    )
    click.echo(report(results, Path(out_dir)))
    if not quiet:
        click.echo(f"({time.perf_counter() - start:.1f} s)", err=True)


def _plan(kind: str, kw: dict[str, Any]) -> plans.Plan:
    dwell, settle, record = kw["dwell"], kw["settle"], kw["record"]
    if kind == "steps":
        return plans.steps(
            kw["start"],
            kw["stop"],
            kw["step"],
            low_pct=kw["low"],
            dwell_s=dwell,
            low_dwell_s=kw["low_dwell"] or dwell,
            settle=settle,
            record_s=record,
            repeats=kw["repeats"],
        )
    if kind in ("stairs-up", "stairs-down"):
        return plans.stairs(
            kw["start"],
            kw["stop"],
            kw["step"],
            down=kind == "stairs-down",
            dwell_s=dwell,
            settle=settle,
            record_s=record,
            repeats=kw["repeats"],
        )
    if kind == "ramp":
        return plans.ramp(kw["start"], kw["stop"], duration_s=kw["duration"], repeats=kw["repeats"])
    levels = [float(x) for x in (kw["levels"] or "").split(",") if x.strip()]
    return plans.explicit(levels, dwell_s=dwell, settle=settle, record_s=record)


class _Readout:
    """The live line while the motor spins: throttle, thrust, V, A, rpm, tightest margin, ETA."""

    def __init__(self, quiet: bool) -> None:
        self.quiet = quiet
        self.last = 0.0
        self.tty = sys.stderr.isatty()

    def __call__(self, st: Status) -> None:
        if self.quiet:
            return
        now = time.monotonic()
        if now - self.last < (0.2 if self.tty else 5.0):
            return
        self.last = now
        r = st.reading
        frac = min(st.elapsed_s / st.plan_duration_s, 1.0) if st.plan_duration_s else 0.0
        bar = "#" * int(20 * frac) + "-" * (20 - int(20 * frac))
        tight = min(st.margins.items(), key=lambda kv: kv[1], default=None)
        margin = f" margin {tight[0]} {tight[1] * 100:.0f}%" if tight else ""

        def f(x: float | None, fmt: str) -> str:
            return "-" if x is None else format(x, fmt)

        line = (
            f"[{bar}] {st.elapsed_s:5.0f}/{st.plan_duration_s:.0f} s  seg {st.segment + 1}/{st.segments} "
            f"{st.label:<12} thr {st.throttle_pct:5.1f}% ({st.throttle_native:.0f})  T {f(r.thrust_n, '.2f')} N  "
            f"{f(r.voltage_v, '.2f')} V  {f(r.current_a, '.1f')} A  {f(r.rpm, '.0f')} rpm{margin}"
        )
        click.echo(("\r" + line) if self.tty else line, err=True, nl=not self.tty)


@click.command("sweep")
@click.argument("kind", type=click.Choice(list(plans.PLANS)))
@click.option(
    "--stand",
    "stand_url",
    required=True,
    help="Stand URL: serial path, sim://tyto-1585, replay://x.jsonl ...",
)
@click.option(
    "--throttle",
    "throttle_url",
    help="Throttle output URL (FC over MSP/MAVLink); omit to drive the ESC from the stand.",
)
@click.option(
    "--fc",
    "fc_kind",
    type=click.Choice(["auto", "msp", "px4", "ardupilot"]),
    default="auto",
    show_default=True,
)
@click.option(
    "--motor",
    default=1,
    show_default=True,
    help="Motor on the load cell (1-based, as FCs number them).",
)
@click.option(
    "--rotors-on-esc",
    type=click.Choice(["1", "4"]),
    default="1",
    show_default=True,
    help="1 = SR, 4 = MR (all four get the command).",
)
@click.option(
    "-o",
    "--output",
    required=True,
    type=click.Path(dir_okay=False),
    help="Ds log to write (CSV + .meta.json).",
)
@click.option(
    "--from", "start", type=float, default=10.0, show_default=True, help="First level, % throttle."
)
@click.option(
    "--to", "stop", type=float, default=60.0, show_default=True, help="Last level, % throttle."
)
@click.option("--step", type=float, default=5.0, show_default=True, help="Increment, %.")
@click.option(
    "--low", type=float, default=10.0, show_default=True, help="steps: level to return to, %."
)
@click.option("--levels", help="explicit: comma-separated levels, %.")
@click.option(
    "--dwell",
    type=float,
    default=3.0,
    show_default=True,
    help="Seconds per level (maximum with --settle).",
)
@click.option("--low-dwell", type=float, help="steps: seconds at the low level (default: --dwell).")
@click.option(
    "--settle",
    is_flag=True,
    help="Hold each level until thrust settles, then --record s (saves battery).",
)
@click.option(
    "--record", type=float, default=1.0, show_default=True, help="Seconds recorded after settling."
)
@click.option(
    "--duration", type=float, default=30.0, show_default=True, help="ramp: seconds per ramp."
)
@click.option("--repeats", type=int, default=1, show_default=True)
@click.option("--max-throttle", type=float, default=80.0, show_default=True, help="Ceiling, %.")
@click.option("--max-thrust", type=float, default=20.0, show_default=True, help="N.")
@click.option("--max-current", type=float, default=60.0, show_default=True, help="A.")
@click.option("--min-cell-voltage", type=float, default=3.3, show_default=True, help="V per cell.")
@click.option("--cells", type=int, help="Battery cells (default: as the FC reports).")
@click.option("--max-rpm", type=float, default=40000.0, show_default=True)
@click.option("--max-temp", type=float, default=90.0, show_default=True, help="°C.")
@click.option("--max-vibration", type=float, default=8.0, show_default=True, help="g.")
@click.option("--max-slew", type=float, default=100.0, show_default=True, help="%/s.")
@click.option(
    "--stale-s",
    type=float,
    default=0.5,
    show_default=True,
    help="Stop when the stand is silent this long.",
)
@click.option(
    "--link-timeout",
    type=float,
    default=1.0,
    show_default=True,
    help="Stop when the FC is silent this long.",
)
@click.option(
    "--tyto-calibration",
    type=click.Path(dir_okay=False),
    help="Per-unit Tyto 1585 calibration JSON.",
)
@click.option(
    "--line-preset", help="Line stand preset (thrustmap-line, rp2040-whoop, stm32-hx711)."
)
@click.option(
    "--realtime/--fast",
    default=None,
    help="Simulated rigs run as fast as possible unless --realtime.",
)
@click.option(
    "--dry-run",
    is_flag=True,
    help="Print the timeline and check it against the limits; spin nothing.",
)
@click.option(
    "-y",
    "--yes",
    is_flag=True,
    help="Do not ask whether the propellers are on and the area is clear.",
)
@click.option("-q", "--quiet", is_flag=True, help="No live readout (for scripts and CI).")
def sweep_cmd(
    kind: str,
    stand_url: str,
    throttle_url: str | None,
    fc_kind: str,
    motor: int,
    rotors_on_esc: str,
    output: str,
    **kw: Any,
) -> None:
    """Run a step/stairs/ramp sweep on a stand and record it as a Ds log.

    Every way out — completion, a tripped limit, an error, Ctrl-C, SIGTERM, a silent stand or
    FC — stops the motor and verifies the stop; the log is kept and marked with the outcome."""
    plan = _plan(kind, kw)
    limits = Limits(
        max_thrust_n=kw["max_thrust"],
        max_current_a=kw["max_current"],
        min_cell_voltage_v=kw["min_cell_voltage"],
        cells=kw["cells"],
        max_rpm=kw["max_rpm"],
        max_temperature_c=kw["max_temp"],
        max_vibration_g=kw["max_vibration"],
        max_throttle_pct=kw["max_throttle"],
        max_slew_pct_s=kw["max_slew"],
        stale_data_s=kw["stale_s"],
        link_timeout_s=kw["link_timeout"],
    )
    check_plan(plan, limits)
    if motor < 1:
        raise ConfigError(f"--motor is 1-based, got {motor}")
    if kw["dry_run"]:
        click.echo(plan.describe())
        click.echo(
            f"limits ok: ceiling {plan.max_throttle_pct:.1f} % <= {limits.max_throttle_pct:.1f} %, "
            f"ramp slew {plan.max_ramp_slew_pct_s():.2f} %/s <= {limits.max_slew_pct_s:.1f} %/s"
        )
        return
    from thrustmap.files import check_output_path, new_recording_path
    from thrustmap.rig import connect

    chosen = new_recording_path(
        check_output_path(output, what="Ds log").path, siblings=(".meta.json",)
    )
    if str(chosen) != output:  # a sweep never overwrites a recording
        click.echo(f"{output} already holds a recording: recording to {chosen} instead", err=True)
        output = str(chosen)
    simulated = connect.is_simulated(stand_url) and (
        throttle_url is None or connect.is_simulated(throttle_url)
    )
    realtime = kw["realtime"] if kw["realtime"] is not None else not simulated
    clock: Clock = MonotonicClock() if realtime else SimClock()
    if not kw["yes"]:
        click.confirm(
            f"{plan.describe().splitlines()[0]}\nPropellers on, stand secured and the area clear?",
            abort=True,
            err=True,
        )
    # SIGTERM unwinds like Ctrl-C from the moment a device is open, so every exit stops motors.
    with terminate_as_exception():
        stand = connect.open_stand(
            stand_url, clock, calibration=kw["tyto_calibration"], line_preset=kw["line_preset"]
        )
        with stand:
            if throttle_url is None:
                output_dev = connect.stand_esc_output(stand)
            else:
                output_dev = connect.open_throttle_output(
                    throttle_url, clock, kind=None if fc_kind == "auto" else fc_kind
                )
            with output_dev:
                result = record_sweep(
                    plan,
                    output_dev,
                    stand,
                    output,
                    clock,
                    limits=limits,
                    config=RunConfig(motor=motor - 1, rotors_on_esc=int(rotors_on_esc)),
                    monitor=_Readout(kw["quiet"]),
                )
    if not kw["quiet"]:
        click.echo("", err=True)
    verdict = (
        "stop verified" if result.stop_verified else "STOP NOT VERIFIED - disconnect the battery"
    )
    click.echo(
        f"{result.status}: {result.samples} samples in {result.duration_s:.1f} s"
        + (f" - {result.reason}" if result.reason else "")
        + f"; {verdict}; log {output}"
    )
    if result.status != "completed" or not result.stop_verified:
        sys.exit(3)
