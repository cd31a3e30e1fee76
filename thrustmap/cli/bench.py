"""CLI: sweep (a bench run with interlocks, recorded as a Ds log) and demo (the simulator)."""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import click

import thrustmap.rig.segments as segments
from thrustmap.cli.mavlink_options import signing_key_option
from thrustmap.cli.textwidth import echo, width
from thrustmap.rig import plans
from thrustmap.rig.interlocks import INTERLOCKS, Limits, check_plan

FC = TypeVar("FC", bound=Callable[..., Any])

if TYPE_CHECKING:
    pass


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
    from thrustmap.demo import report, report_path, run_demo

    start = time.perf_counter()
    results = run_demo(
        Path(out_dir),
        seed=seed,
        progress=None if quiet else (lambda m: echo(m, err=True)),
        reports=True,
        parallel=None,  # SR and MR in two worker processes where there are two cores
    )
    echo(report(results, Path(out_dir), cols=width()))
    for r in results:
        echo(f"Report: {report_path(r)} (open it in a browser)")
    if not quiet:
        click.echo(f"({time.perf_counter() - start:.1f} s)", err=True)


def _plan(kind: str, kw: dict[str, Any]) -> plans.Plan:
    from thrustmap.core.errors import ConfigError

    if kind != "adaptive" and (kw.get("across_voltage") or kw.get("voltage_range")):
        raise ConfigError("--across-voltage and --voltage-range are for sweep adaptive")
    if kw["repeats"] < 1:
        raise ConfigError(f"--repeats {kw['repeats']}: expected 1 or more")
    if not kw["record"] > 0:  # also NaN
        raise ConfigError(f"--record {kw['record']:g}: expected a positive number of seconds")
    dwell, settle, record = kw["dwell"], kw["settle"], kw["record"]
    if kind == "steps":
        return plans.steps(
            kw["start"],
            kw["stop"],
            kw["step"],
            low=plans.Low(kw["low"], kw["low_dwell"] or dwell),
            dwell_s=dwell,
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
    if kind == "adaptive":
        return _adaptive_plan(kw)
    return plans.explicit(_levels(kw["levels"]), dwell_s=dwell, settle=settle, record_s=record)


def _levels(text: str | None) -> list[float]:
    """``--levels 10,20,35``: finite throttle levels in 0..100 %, named when one is not."""
    from thrustmap.core.errors import ConfigError

    if not text or not text.strip():
        raise ConfigError("explicit needs --levels: comma-separated throttle levels in %")
    levels = []
    for i, part in enumerate(text.split(","), start=1):
        if not part.strip():
            continue  # "10,20," and "10,,20": an empty item is no level
        try:
            value = float(part)
        except ValueError:
            raise ConfigError(
                f"--levels: item {i} {part.strip()!r} is not a number; expected "
                "comma-separated throttle levels in % (e.g. 10,20,35)"
            ) from None
        if not 0.0 <= value <= 100.0:  # also NaN and inf
            raise ConfigError(f"--levels: item {i} is {value:g}; expected 0..100 % throttle")
        levels.append(value)
    if not levels:
        raise ConfigError(f"--levels {text!r}: no level; expected e.g. 10,20,35 (% throttle)")
    return levels


def _stand_cannot_see_the_motor(stand_url: str | None, throttle_url: str | None) -> bool:
    """A simulated stand with a real throttle output: its thrust is noise whatever spins."""
    from thrustmap.rig.devices.urls import is_simulated

    return (
        stand_url is not None
        and throttle_url is not None
        and is_simulated(stand_url)
        and not is_simulated(throttle_url)
    )


def _adaptive_plan(kw: dict[str, Any]) -> plans.Plan:
    """``sweep adaptive``: every hold settles (``--dwell`` is its maximum); the chooser fits
    the points as they come (``thrustmap.fitting.adaptive``)."""
    from thrustmap.core.errors import ConfigError
    from thrustmap.fitting.adaptive import MapChooser

    thrust_range = None
    if kw["thrust_range"]:
        try:
            lo, hi = (float(x) for x in kw["thrust_range"].split(":"))
        except ValueError:
            raise ConfigError(
                f"--thrust-range {kw['thrust_range']!r}: expected LO:HI in newtons, e.g. 0.5:8"
            ) from None
        thrust_range = (lo, hi)
        cap = Limits.from_options(kw).max_thrust_n
        if hi > cap:
            raise ConfigError(
                f"--thrust-range top {hi:g} N is above the thrust limit {cap:g} N (--max-thrust)"
            )
    voltage_range = _voltage_range(kw)
    chooser = MapChooser(
        kw["target_pi"], thrust_range_n=thrust_range, voltage_range_v=voltage_range
    )
    across = (
        None
        if voltage_range is None
        else plans.AcrossVoltage(
            voltage_range, kw.get("connect_pack"), discharge=kw.get("discharge", True)
        )
    )
    return plans.adaptive(
        chooser,
        kw["start"],
        kw["stop"],
        coarse_levels=kw["coarse"],
        dwell_s=kw["dwell"],
        record_s=kw["record"],
        budget=plans.Budget(kw["max_minutes"], kw["max_wh"]),
        across=across,
    )


def _voltage_range(kw: dict[str, Any]) -> tuple[float, float] | None:
    """``--across-voltage --voltage-range LO:HI`` (volts at the battery, as the stand reads
    them); either alone is refused."""
    from thrustmap.core.errors import ConfigError

    text, across = kw.get("voltage_range"), kw.get("across_voltage")
    if not across:
        if text:
            raise ConfigError("--voltage-range is for --across-voltage: give both")
        return None
    if not text:
        raise ConfigError("--across-voltage needs --voltage-range LO:HI in volts, e.g. 21:25")
    try:
        lo, hi = (float(x) for x in text.split(":"))
    except ValueError:
        raise ConfigError(
            f"--voltage-range {text!r}: expected LO:HI in volts, e.g. 21:25"
        ) from None
    if not (0 < lo < hi < 100):  # also NaN
        raise ConfigError(f"--voltage-range {text!r}: expected 0 < LO < HI < 100 V")
    return lo, hi


def _pack_prompt(where: dict[str, str], *, quiet: bool) -> Callable[[segments.PackChange], bool]:
    """The question a pack change asks, with the motor stopped and the stop verified. A
    simulated bench (sim:// stand and FC) connects the asked pack itself; a real one asks on
    stderr/stdin, then the safety question of every spin (``confirm_spin``, asked even with
    --yes: a human has just had a hand at the stand). No answer or a no: no pack, the run ends
    (the motor stays stopped)."""
    from thrustmap.cli.spin_confirm import Refused, confirm_spin

    def connect(change: segments.PackChange) -> bool:
        from thrustmap.rig.devices.urls import is_simulated

        stand, throttle = where.get("stand", ""), where.get("throttle", "")
        if stand and throttle and is_simulated(stand) and is_simulated(throttle):
            from urllib.parse import parse_qs, urlsplit

            from thrustmap.rig.sim import peers

            bench = parse_qs(urlsplit(stand).query).get("bench", ["default"])[0]
            plant = peers.bench_plant({"bench": bench})
            plant.connect_pack(plant.time_s, ocv_v=change.wanted_v)
            if not quiet:
                click.echo(
                    f"simulated bench: a pack at {change.wanted_v:.2f} V connected", err=True
                )
            return True
        click.echo(change.message, err=True)
        try:
            confirm_spin(
                "Other pack connected, propellers on, stand secured and the area clear?",
                yes=False,
            )
        except Refused:
            return False
        return True

    return connect


def limit_options(fn: FC) -> FC:
    """One click option per row of the interlock table (``rig.interlocks.INTERLOCKS``): its
    option name, its default and its unit come from the table, never from here."""
    return limit_options_except()(fn)


def limit_options_except(*exclude: str) -> Callable[[FC], FC]:
    """``limit_options`` without the rows named in ``exclude`` (``spin`` sets its own, lower
    throttle cap)."""

    def decorate(fn: FC) -> FC:
        for row in reversed(INTERLOCKS):
            if row.field in exclude:
                continue
            unit = f" [{row.unit}]" if row.unit else ""
            fn = click.option(
                row.option,
                row.field,
                type=row.value_type,
                default=row.default,
                show_default=row.default is not None,
                help=row.help + unit,
            )(fn)
        return fn

    return decorate


def _calibration(tyto: str | None, line: str | None) -> str | None:
    from thrustmap.core.errors import ConfigError

    if tyto is not None and line is not None:
        raise ConfigError("give --tyto-calibration or --line-calibration, not both")
    return tyto if tyto is not None else line


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
    default="1",
    show_default=True,
    help="Motor on the load cell: the FC's motor number, 1-based (ArduPilot MotorN, PX4 MOTOR N,"
    " Betaflight motor N); on ArduPilot also the test-order letter (A, B, ...).",
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
@click.option(
    "--target-pi",
    type=float,
    default=1.0,
    show_default=True,
    help="adaptive: stop once the map's 95 % prediction interval is within this many % "
    "throttle over the envelope.",
)
@click.option(
    "--thrust-range",
    help="adaptive: the envelope LO:HI in N (default: the coarse pass's thrusts, up to the "
    "thrust at --to).",
)
@click.option(
    "--max-minutes",
    type=float,
    default=10.0,
    show_default=True,
    help="adaptive: bench-time budget.",
)
@click.option("--max-wh", type=float, help="adaptive: battery-energy budget, Wh.")
@click.option(
    "--across-voltage",
    is_flag=True,
    help="adaptive: measure across --voltage-range (discharging the pack, or asking for "
    "another with the motor stopped) until the interval holds over it.",
)
@click.option(
    "--voltage-range",
    help="adaptive --across-voltage: battery voltages LO:HI in V the map must cover.",
)
@click.option(
    "--discharge/--no-discharge",
    default=True,
    show_default=True,
    help="adaptive --across-voltage: reach a lower voltage by discharging the pack, or ask "
    "for another pack (quicker when one is at hand).",
)
@click.option(
    "--coarse",
    type=int,
    default=5,
    show_default=True,
    help="adaptive: levels in the coarse pass, --from to --to.",
)
@limit_options
@click.option(
    "--tyto-calibration",
    type=click.Path(dir_okay=False),
    help="Per-unit Tyto 1585 calibration JSON.",
)
@click.option(
    "--line-preset", help="Line stand preset (thrustmap probe names it; e.g. thrustmap-line)."
)
@click.option(
    "--realtime/--fast",
    default=None,
    help="Simulated rigs run as fast as possible unless --realtime.",
)
@click.option("--line-spec", type=click.Path(dir_okay=False), help="Line stand spec (JSON).")
@click.option(
    "--line-calibration",
    type=click.Path(dir_okay=False),
    help="Line stand load-cell calibration (from thrustmap stand calibrate).",
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
@click.option("-q", "--quiet", is_flag=True, help="Only the summary (no live view).")
@click.option(
    "--sim-apart",
    is_flag=True,
    help="With a sim:// stand and a sim:// FC: keep them on separate simulated benches (the "
    "stand then measures a rotor nothing drives, like a thrown propeller). By default they "
    "form one bench.",
)
@signing_key_option
def sweep_cmd(
    kind: str,
    stand_url: str,
    throttle_url: str | None,
    fc_kind: str,
    motor: str,
    rotors_on_esc: str,
    output: str,
    **kw: Any,
) -> None:
    """Run a step/stairs/ramp sweep, or an adaptive run, on a stand and record it as a Ds log.

    adaptive (the recommended way to calibrate): a short coarse pass, then one settled hold at
    a time where the map being fitted is least certain at the battery voltage now, until its
    95 % interval is within --target-pi over the envelope or a budget (--max-minutes,
    --max-wh) or a limit ends the run; the log's sidecar says why each point was chosen.

    Every way out — completion, a tripped limit, an error, Ctrl-C, SIGTERM, a silent stand or
    FC — stops the motor and verifies the stop; the log is kept and marked with the outcome.
    Before the plan the rotor must be at rest and the stand is tared (shown as its own phase).

    \b
    Exit codes:
      0    done (stop verified)
      1    aborted by a limit or a device failure (stop verified)
      2    refused or bad input (nothing spun)
      3    stop NOT verified (disconnect the battery)
      130  interrupted by Ctrl-C/SIGTERM (stop verified)"""
    from thrustmap.rig.run_types import RunConfig
    from thrustmap.rig.session import BenchSession, Rig, choose_clock, exit_code, pairing_warnings

    where: dict[str, str] = {}  # the rig's URLs, for a pack change's question
    kw["connect_pack"] = _pack_prompt(where, quiet=kw["quiet"])
    plan = _plan(kind, kw)
    limits = Limits.from_options(kw)
    check_plan(plan, limits)
    from thrustmap.cli.live import LiveView
    from thrustmap.rig.fc.motor_numbers import parse_motor
    from thrustmap.rig.sim.pairing import pair_sim_urls

    motor_number, _ = parse_motor(motor)  # refuse a bad --motor before anything is opened
    rig = Rig(
        stand=pair_sim_urls(stand_url, throttle_url, apart=kw["sim_apart"]),
        throttle=throttle_url,
        kind=None if fc_kind == "auto" else fc_kind,
        calibration=_calibration(kw["tyto_calibration"], kw["line_calibration"]),
        line_preset=kw["line_preset"],
        line_spec=kw["line_spec"],
        motor=(motor_number or 1) - 1,
        watchdog_log=str(Path(output).with_suffix(".watchdog.log")),  # beside the recording
        signing_key=kw["signing_key"],
    )
    where.update(stand=rig.stand or "", throttle=rig.throttle or "")
    for warning in pairing_warnings(rig):
        echo(f"warning: {warning}", err=True)
    if _stand_cannot_see_the_motor(rig.stand, rig.throttle) and limits.min_thrust_by_pct > 0:
        # a simulated stand beside a real motor measures noise by design: the thrust-response
        # interlock would stop every such run, so it is off, and said so
        limits = dataclasses.replace(limits, min_thrust_by_pct=0.0)
        echo(
            "warning: the thrust-response interlock (--min-thrust-by) is off: "
            "a simulated stand cannot measure a real motor",
            err=True,
        )
    if kw["dry_run"]:
        echo(plan.describe())
        echo(
            f"limits ok: ceiling {plan.max_throttle_pct:.1f} % <= {limits.max_throttle_pct:.1f} %, "
            f"ramp slew {plan.max_ramp_slew_pct_s():.2f} %/s <= {limits.max_slew_pct_s:.1f} %/s"
        )
        return
    from thrustmap.core.files import check_output_path, new_recording_path

    chosen = new_recording_path(
        check_output_path(output, what="Ds log", renamed=True).path, siblings=(".meta.json",)
    )
    if str(chosen) != output:  # a sweep never overwrites a recording
        echo(f"{output} already holds a recording: recording to {chosen} instead", err=True)
        output = str(chosen)
        rig = dataclasses.replace(rig, watchdog_log=str(chosen.with_suffix(".watchdog.log")))
    realtime = kw["realtime"]
    clock = choose_clock(
        rig.urls(), "auto" if realtime is None else ("real" if realtime else "sim")
    )
    from thrustmap.cli.spin_confirm import confirm_spin

    confirm_spin(
        f"{plan.describe().splitlines()[0]}\nPropellers on, stand secured and the area clear?",
        yes=kw["yes"],
    )
    session = BenchSession(rig, clock)
    try:
        with session, LiveView(f"sweep {kind}", quiet=kw["quiet"]) as view:
            motor_index, label = session.resolve_motor(motor)
            view.note(f"motor on the load cell: {label}")
            result = session.sweep(
                plan,
                output,
                limits=limits,
                config=RunConfig(motor=motor_index, rotors_on_esc=int(rotors_on_esc)),
                monitor=view.sweep_monitor,
            )
    except KeyboardInterrupt:  # before the run started (the runner reports its own)
        verified = session.stop_verified is not False
        echo("interrupted; " + ("stop verified" if verified else "STOP NOT VERIFIED"), err=True)
        sys.exit(exit_code("interrupted", verified))
    verified = result.stop_verified and session.stop_verified is not False
    verdict = "stop verified" if verified else "STOP NOT VERIFIED - disconnect the battery"
    blind = session.stop_unverifiable
    if blind and not verified:
        verdict = f"stop sent and acknowledged, NOT verified ({blind})"
    echo(
        f"{result.status}: {result.samples} samples in {result.duration_s:.1f} s"
        + (f" (after {result.wait_s:.1f} s at rest and taring)" if result.wait_s >= 0.05 else "")
        + (f" - {result.reason}" if result.reason else "")
        + f"; {verdict}; log {output}"
    )
    code = exit_code(result.outcome, verified)
    if code:
        sys.exit(code)
