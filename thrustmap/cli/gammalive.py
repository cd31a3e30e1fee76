"""CLI: ``gamma live URL`` — γ(B) fitted while the vehicle flies, from its MAVLink telemetry.

Thin over ``rig.fc.telemetry_stream`` (the link or a replayed recording),
``flightlogs.telemetry`` (messages -> FlightLog) and ``fitting.gamma_live`` (the same
Df extraction and γ fit as `flightlog extract` and `gamma fit`). Heavy imports happen inside
the command, so `thrustmap --help` stays fast.
"""

from __future__ import annotations

import contextlib
import signal
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any

import click

from thrustmap.cli.df_options import LIVE_FIELDS, df_click_options
from thrustmap.cli.mavlink_options import signing_key_option
from thrustmap.core.errors import ConfigError

if TYPE_CHECKING:
    from thrustmap.fitting.gamma_live import LiveState
    from thrustmap.flightlogs.telemetry import Telemetry

PANEL_WIDTH = 80
PANEL_PERIOD_S = 1.0
#: stream time after the first vehicle heartbeat by which voltage and acceleration must flow
STREAMS_GRACE_S = 10.0
#: after the vehicle was airborne and disarmed, keep listening this long (landing messages)
AFTER_DISARM_S = 2.0

EXIT_OK, EXIT_LOST, EXIT_BAD, EXIT_INTERRUPTED = 0, 1, 2, 130


class _Stop(Exception):
    def __init__(self, why: str, code: int) -> None:
        super().__init__(why)
        self.why = why
        self.code = code


@dataclass
class _Flight:
    """Arming and landing as the stream tells them (for the end of the run)."""

    armed_seen: bool = False
    airborne_seen: bool = False
    disarmed_at_s: float | None = None
    notes: list[str] = field(default_factory=list)

    def update(self, tel: Telemetry, t: float) -> bool:
        """True when the flight is over (airborne, then disarmed for AFTER_DISARM_S)."""
        hb = tel.last("HEARTBEAT")
        if hb is None:
            return False
        armed = hb[1] > 0.5
        if armed:
            self.armed_seen = True
            self.disarmed_at_s = None
            land = tel.last("EXTENDED_SYS_STATE")
            alt = tel.last("GLOBAL_POSITION_INT")
            if (land is not None and land[1] < 0.5) or (alt is not None and alt[1] > 1.0):
                self.airborne_seen = True
            return False
        if not self.airborne_seen:
            return False
        if self.disarmed_at_s is None:
            self.disarmed_at_s = t
        return t - self.disarmed_at_s >= AFTER_DISARM_S


def _missing_streams(tel: Telemetry) -> tuple[list[str], list[str]]:
    """(fatal, other): streams a γ fit cannot do without, and ones it is poorer without."""
    fatal, other = [], []
    if not tel.has_voltage():
        fatal.append("battery voltage (SYS_STATUS.voltage_battery)")
    if tel.acceleration_source() is None:
        fatal.append("acceleration (HIGHRES_IMU / SCALED_IMU / RAW_IMU)")
    if not any(tel.rows[k] for k in ("SERVO_OUTPUT_RAW", "ATTITUDE_TARGET", "VFR_HUD")):
        fatal.append("thrust command (SERVO_OUTPUT_RAW / ATTITUDE_TARGET / VFR_HUD)")
    if not tel.rows["EXTENDED_SYS_STATE"]:
        other.append("landed state (EXTENDED_SYS_STATE)")
    if not tel.rows["ATTITUDE"]:
        other.append("attitude (ATTITUDE: no tilt filter)")
    if not tel.rows["GLOBAL_POSITION_INT"] and not tel.rows["VFR_HUD"]:
        other.append("height and climb (GLOBAL_POSITION_INT, VFR_HUD)")
    return fatal, other


def _cut(line: str) -> str:
    return line if len(line) <= PANEL_WIDTH else line[: PANEL_WIDTH - 1] + "…"


def panel_lines(
    url: str, tel: Telemetry, st: LiveState, t_s: float, refused: dict[str, str]
) -> list[str]:
    """The live panel: every line at most 80 columns."""
    from thrustmap.fitting.mapfile import gamma_text

    v = tel.vehicle
    who = "no vehicle yet"
    if v is not None:
        ap = {3: "ArduPilot", 12: "PX4"}.get(v.autopilot, f"autopilot {v.autopilot}")
        hb = tel.last("HEARTBEAT")
        armed = "armed" if hb is not None and hb[1] > 0.5 else "disarmed"
        who = f"{ap} sys {v.system_id}, {armed}"
    lines = [f"gamma live  {url}", f"  {who}   stream {t_s:7.1f} s   Df from {st.duration_s:.1f} s"]
    lines.append(f"  Df kept {st.samples} samples ({st.kept_s:.1f} s)")
    for name, secs, reason in sorted(st.dropped, key=lambda d: -d[1])[:4]:
        lines.append(f"    -{secs:6.1f} s {name}: {reason}")
    if refused:
        lines.append("  not granted: " + ", ".join(f"{k} ({v})" for k, v in refused.items()))
    if st.bins:
        lines.append("  voltage bin      n     γ  ±95%")
        for b in st.bins:
            lines.append(
                f"  {b.lo_v:6.2f}..{b.hi_v:6.2f} {b.samples:5d} {b.gamma_mean:6.4f} "
                f"{b.gamma_ci95:.4f}"
            )
    fit = st.gamma_fit
    if fit is not None:
        c = fit.correction
        terms = gamma_text(c.coefficients, 4)
        err = fit.heldout.get(fit.degree)
        lines.append(f"  γ(B) = {terms}")
        lines.append(
            f"    degree {fit.degree}, {fit.samples} samples, "
            f"{c.voltage_v.lo:.2f}..{c.voltage_v.hi:.2f} V"
            + (f", held-out ±{err:.4f}" if err is not None else "")
        )
    if st.why_not:
        lines.append(f"  γ not determined: {st.why_not}")
    if st.hover_uncorrected_pct is not None and st.voltage_now_v is not None:
        lines.append(
            f"  hover at {st.voltage_now_v:.2f} V: map {st.hover_uncorrected_pct:.1f} %, "
            f"with γ {st.hover_corrected_pct:.1f} %"
        )
    if st.hover_ours is not None or st.hover_vehicle is not None:
        ours = "–" if st.hover_ours is None else f"{st.hover_ours:.3f}"
        theirs = (
            "not streamed"
            if st.hover_vehicle is None
            else f"{st.hover_vehicle:.3f} {st.hover_vehicle_source}"
        )
        lines.append(f"  hover throttle ours {ours}, vehicle {theirs}")
    return [_cut(x) for x in lines]


class _Panel:
    """Redrawn in place on a terminal (stderr), at most once a second; silent elsewhere."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled and sys.stderr.isatty()
        self._drawn = 0
        self._last_s = -1e9

    def due(self, wall_s: float) -> bool:
        return self.enabled and wall_s - self._last_s >= PANEL_PERIOD_S

    def draw(self, lines: list[str], wall_s: float) -> None:
        self._last_s = wall_s
        out = "\x1b[F\x1b[2K" * self._drawn + "\n".join(lines) + "\n"
        sys.stderr.write(out)
        sys.stderr.flush()
        self._drawn = len(lines)

    def erase(self) -> None:
        if self.enabled and self._drawn:
            sys.stderr.write("\x1b[F\x1b[2K" * self._drawn)
            sys.stderr.flush()
            self._drawn = 0


@contextmanager
def _signals_as_stop() -> Iterator[None]:
    """SIGTERM (and SIGHUP) end the run as Ctrl-C does: the files are written, exit 130."""
    from thrustmap.rig.sigterm import terminate_as_exception

    with terminate_as_exception(stopping="listening (writing what was received)"):
        yield


@contextmanager
def _deferred() -> Iterator[list[int]]:
    """While the files are written, a second Ctrl-C or SIGTERM is noted, not obeyed."""
    seen: list[int] = []

    def note(signum: int, frame: FrameType | None) -> None:
        seen.append(signum)

    previous = {}
    for name in ("SIGINT", "SIGTERM", "SIGHUP"):
        sig = getattr(signal, name, None)
        if sig is not None:
            with contextlib.suppress(ValueError):  # not the main thread
                previous[sig] = signal.signal(sig, note)
    try:
        yield seen
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


@click.command("live")
@click.argument("url")
@click.option(
    "--map",
    "map_path",
    required=True,
    type=click.Path(path_type=Path),
    help="Stand map (per rotor).",
)
@df_click_options(LIVE_FIELDS, required=("mass_kg",))
@click.option(
    "-o",
    "--output",
    type=click.Path(path_type=Path),
    help="Corrected map (written when γ is determined).",
)
@click.option(
    "--df",
    "df_path",
    type=click.Path(path_type=Path),
    help="Df CSV (+ sidecar) to write [default: beside -o, or gamma-live.csv].",
)
@click.option(
    "--record", type=click.Path(path_type=Path), help="Write the raw telemetry to this new .tlog."
)
@click.option("--loss", type=click.Choice(["l1", "l2"]), default="l1", show_default=True)
@click.option(
    "--link-timeout-s",
    type=float,
    default=5.0,
    show_default=True,
    help="Silence that counts as a lost link.",
)
@click.option(
    "--start-timeout-s",
    type=float,
    default=30.0,
    show_default=True,
    help="Wait this long for a vehicle.",
)
@click.option("--no-panel", is_flag=True, help="No live panel (it is drawn only on a terminal).")
@click.option("--json", "as_json", is_flag=True, help="Print the final state as JSON.")
@signing_key_option
def gamma_live_cmd(
    url: str,
    map_path: Path,
    output: Path | None,
    df_path: Path | None,
    record: Path | None,
    loss: str,
    link_timeout_s: float,
    start_timeout_s: float,
    no_panel: bool,
    as_json: bool,
    signing_key: Any,
    **df_values: Any,
) -> None:
    """Fit γ(B) while the vehicle flies, from its MAVLink telemetry at URL.

    URL is a live link as `probe` takes it (udpin:127.0.0.1:14550, udpout:HOST:PORT,
    tcp:HOST:PORT, a serial device) or replay://flight.tlog, a recording made with --record.
    The Df comes from the same code and filters as `flightlog extract`, the γ fit from the
    same code as `gamma fit`.

    SAFETY: it only listens. It sends no HEARTBEAT and no command that could arm, move or
    change the vehicle: only MAV_CMD_SET_MESSAGE_INTERVAL for the messages it needs (not saved
    by the autopilot; REQUEST_DATA_STREAM is never sent, ArduPilot would save it) and reads of
    a few parameters. It can listen beside a ground station on a forwarded stream.

    It ends when the vehicle has flown and disarmed (exit 0), on Ctrl-C or SIGTERM (exit 130),
    on a lost link (exit 1); each way it writes the Df (CSV + sidecar), the corrected map when
    γ is determined (otherwise it says why not) and the recording. A stream without battery
    voltage, acceleration or a thrust command is named at the start (exit 2: no γ possible).
    """
    from thrustmap.fitting.df_options import DfOptions
    from thrustmap.fitting.gamma_live import LiveGamma
    from thrustmap.fitting.mapfile import ThrustMap
    from thrustmap.flightlogs.telemetry import Telemetry
    from thrustmap.rig.fc.telemetry_stream import LinkLost, open_stream

    if not df_values["mass_kg"] > 0:
        raise ConfigError(f"--mass-kg must be positive, got {df_values['mass_kg']}")
    df_path = _check_outputs(url, map_path, output, df_path, record)
    tmap = ThrustMap.load(map_path)
    opts = DfOptions(**df_values)
    stream = open_stream(
        url,
        record=record,
        link_timeout_s=link_timeout_s,
        start_timeout_s=start_timeout_s,
        signing_key=signing_key,
    )
    tel = Telemetry(url, "tlog")
    live = LiveGamma(tel, opts, tmap, loss=loss)
    panel = _Panel(not no_panel)
    code, why = EXIT_OK, ""
    try:
        with _signals_as_stop():
            try:
                why = _listen(url, stream, tel, live, panel)
            except LinkLost as exc:
                code, why = EXIT_LOST, f"lost link: {exc}"
            except _Stop as exc:
                code, why = exc.code, exc.why
    except KeyboardInterrupt:
        code, why = EXIT_INTERRUPTED, "interrupted"
    finally:
        panel.erase()
        with _deferred():
            try:
                stream.close()
            finally:
                summary = _finish(url, tel, live, df_path, output, record, code, as_json)
    head = {EXIT_OK: "", EXIT_LOST: "error: ", EXIT_BAD: "error: ", EXIT_INTERRUPTED: ""}[code]
    if tel.vehicle is None and code != EXIT_BAD:
        why = why or "no vehicle heard"
    click.echo(f"{head}{why}; {summary}" if why else summary, err=code != EXIT_OK)
    if code:
        sys.exit(code)


def _check_outputs(
    url: str, map_path: Path, output: Path | None, df_path: Path | None, record: Path | None
) -> Path:
    """Every file the run will write, checked before it listens (none may be an input); the
    Df's path (beside -o, or gamma-live.csv, when not given)."""
    from thrustmap.core.files import check_output_path
    from thrustmap.fitting.df.dffile import sidecar_path

    if df_path is None:
        df_path = output.with_suffix(".df.csv") if output is not None else Path("gamma-live.csv")
    inputs: list[Path] = [map_path]
    if url.lower().startswith("replay://"):
        inputs.append(Path(url[len("replay://") :]))
    check_output_path(df_path, inputs=inputs, what="Df output")
    check_output_path(sidecar_path(df_path), inputs=inputs, what="Df sidecar")
    if output is not None:
        check_output_path(output, inputs=inputs, what="map output")
    if record is not None:
        check_output_path(record, inputs=inputs, what="recording")
    return df_path


def _listen(url: str, stream: Any, tel: Telemetry, live: Any, panel: _Panel) -> str:
    """Read the stream until the flight is over or the stream ends; why it stopped. The streams
    are judged STREAMS_GRACE_S after the first heartbeat, or at the end if that came sooner (a
    γ fit impossible: ``_Stop``)."""
    import time

    flight = _Flight()
    first_hb_t: float | None = None
    streams_checked = False
    for t, msg in stream.messages():
        tel.add(msg, t)
        if first_hb_t is None and tel.vehicle is not None:
            first_hb_t = t
        if not streams_checked and first_hb_t is not None and t - first_hb_t >= STREAMS_GRACE_S:
            streams_checked = True
            _check_streams(tel, stream.requests.refused())
        if flight.update(tel, t):
            why = "landed and disarmed"
            break
        if panel.enabled and live.due(t) and tel.vehicle is not None:
            live.refit(t)
        wall = time.monotonic()
        if panel.due(wall):
            lines = panel_lines(
                url, tel, live.state, t - (first_hb_t or t), stream.requests.refused()
            )
            panel.draw(lines, wall)
    else:
        why = "end of the recording" if url.lower().startswith("replay://") else "stream ended"
    if not streams_checked and tel.vehicle is not None:
        fatal, _ = _missing_streams(tel)
        if fatal:
            raise _Stop("the stream lacks " + "; ".join(fatal) + ": γ cannot be fitted", EXIT_BAD)
    return why


def _check_streams(tel: Telemetry, refused: dict[str, str]) -> None:
    """The streams a γ fit needs, once: those it is poorer without are a warning, those it
    cannot do without stop the run (``_Stop``, exit 2)."""
    fatal, other = _missing_streams(tel)
    if other:
        click.echo("warning: the stream lacks " + "; ".join(other), err=True)
    if fatal:
        raise _Stop(
            "the stream lacks "
            + "; ".join(fatal)
            + ": γ cannot be fitted"
            + (f" (refused: {', '.join(refused)})" if refused else ""),
            EXIT_BAD,
        )


def _finish(
    url: str,
    tel: Telemetry,
    live: Any,
    df_path: Path,
    output: Path | None,
    record: Path | None,
    code: int,
    as_json: bool,
) -> str:
    """Write what there is: the Df, the corrected map when γ is determined. One line back."""
    import json

    from thrustmap.core.errors import FitError
    from thrustmap.fitting.df.dffile import read_df, write_df
    from thrustmap.fitting.gamma import GammaOptions, corrected_map, fit_gamma, physical_refusals
    from thrustmap.fitting.mapfile import file_sha256
    from thrustmap.fitting.mapfile import gamma_text as formula

    wrote: list[str] = []
    if record is not None and record.exists():
        wrote.append(f"recording {record}")
    if tel.vehicle is None or tel.acceleration_source() is None or code == EXIT_BAD:
        return ("wrote " + ", ".join(wrote)) if wrote else "nothing written (no Df possible)"
    st = live.compute(quiet=True)
    if st.df is None:
        return f"no Df ({st.why_not})" + (f"; wrote {', '.join(wrote)}" if wrote else "")
    st.df.sources["telemetry"] = {"url": url, "record": None if record is None else str(record)}
    write_df(st.df, df_path)
    wrote.insert(0, f"Df {df_path} ({st.samples} samples)")
    gamma_text = f"γ not determined ({st.why_not}): no corrected map written"
    fit = None
    if st.gamma_fit is not None:
        # the final fit reads the Df back as `gamma fit` does: the same numbers as running it
        table, side = read_df(df_path)
        try:
            how = GammaOptions(loss="l1" if live.loss == "l1" else "l2")
            tried = fit_gamma(table, side, live.tmap, how)
            refused = physical_refusals(tried) if tried.corrected else []
            if refused:  # the γ band and the Df length, as `gamma fit` applies them
                raise FitError("; ".join(refused) + f"; `gamma fit {df_path} --force` writes it")
            fit = tried
        except Exception as exc:  # a refusal of the fit is reported, never lost
            gamma_text = f"γ not determined ({exc}): no corrected map written"
    if fit is not None and fit.corrected:
        c = fit.correction
        terms = formula(c.coefficients, 6)
        gamma_text = f"γ(B) = {terms} (degree {fit.degree}, {fit.samples} samples)"
        if output is not None:
            from thrustmap.core.files import atomic_write_text

            sources = [{"path": str(df_path), "sha256": file_sha256(df_path)}]
            atomic_write_text(output, corrected_map(live.tmap, fit, sources).dumps())
            wrote.insert(1, f"map {output}")
    elif fit is not None:
        gamma_text = "γ not determined (no γ(B) keeps the map no worse in every populated voltage bin): no corrected map written"
    if as_json:
        click.echo(
            json.dumps(
                {
                    "samples": st.samples,
                    "kept_s": st.kept_s,
                    "duration_s": st.duration_s,
                    "gamma": None if fit is None else fit.to_dict(),
                    "hover_ours": st.hover_ours,
                    "hover_vehicle": st.hover_vehicle,
                    "hover_vehicle_source": st.hover_vehicle_source,
                    "exit_code": code,
                },
                indent=2,
                default=float,
            )
        )
    return f"{gamma_text}; wrote " + ", ".join(wrote)
