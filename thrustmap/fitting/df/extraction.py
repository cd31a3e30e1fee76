"""The extraction: one flight's filters in order and its Df columns, and ``extract`` over
every flight (the sidecar naming each column's origin)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from thrustmap.core.errors import ConfigError, DataFormatError
from thrustmap.fitting.df.airborne import climb_rule, in_air_evidence, rest_calibration
from thrustmap.fitting.df.flight_run import FlightRun
from thrustmap.fitting.df.options import (
    DF_FORMAT,
    G0,
    MIN_ACCEL_RATE_HZ,
    MIN_DF_SAMPLES,
    SATURATED_NORM,
    FlightReport,
)
from thrustmap.fitting.df.resample import (
    bin_mean,
    dilate,
    mask_runs,
    plausible_timeline,
    running_mean,
    steady_mask,
)
from thrustmap.fitting.df.table import Columns, Df, concat_columns
from thrustmap.fitting.df.thrust import (
    map_extrapolation,
    motor_pct_in_map_scale,
    select_motors,
    thrust_from_motors,
)
from thrustmap.fitting.df_options import DfOptions
from thrustmap.flightlogs.series import (
    FlightLog,
    FloatArray,
    nanmedian,
    refuse_unphysical_specific_force,
    specific_force_unit,
)

if TYPE_CHECKING:  # pandas is imported where a table is asked for: `flightlog extract` runs
    import pandas as pd  # without it (its import alone took 0.3 s of a 0.7 s extraction)

    from thrustmap.fitting.mapfile import ThrustMap


def _flight_id(flight: FlightLog) -> str:
    return f"{Path(flight.path).name}#{flight.index}"


def _voltage_missing(flight: FlightLog) -> str | None:
    """Why the flight has no usable battery voltage (None when it has one). The reader already
    questions voltages that cannot be physical (0 V throughout) and leaves them out."""
    if flight.voltage_v is not None and len(flight.voltage_v):
        return None
    why = [w for w in flight.warnings if "voltage" in w or "Volt" in w]
    return "; ".join(why) if why else "not in the log"


def extract_flight(
    flight: FlightLog, opts: DfOptions, tmap: ThrustMap | None = None
) -> tuple[pd.DataFrame, dict[str, Any], FlightReport]:
    """One flight's Df table (pandas), its sidecar entry and its filter report."""
    import pandas as pd

    columns, meta, report = extract_flight_columns(flight, opts, tmap)
    return pd.DataFrame(columns), meta, report


def extract_flight_columns(
    flight: FlightLog, opts: DfOptions, tmap: ThrustMap | None = None
) -> tuple[Columns, dict[str, Any], FlightReport]:
    """As ``extract_flight``, the table as columns of numpy arrays (no pandas needed): the
    flight on one timeline (``_start``), its signals (``_signals``), ``FILTERS`` in order,
    then the Df columns and the "values" filter."""
    flight = select_motors(flight, opts.rotors)
    run = _start(flight, opts, tmap)
    _signals(run)
    for rule in FILTERS:
        rule(run)
    cols, sources, rotors = _columns(run)
    valid = np.isfinite(run.a_up) & (run.a_up > 0)
    if run.voltage_unknown is None:
        valid &= np.isfinite(run.volt) & (run.volt > 0)
    cmd = cols.get("thrust_cmd_n", cols.get("thrust_cmd_norm", cols.get("throttle_pct")))
    if cmd is not None:
        valid &= np.isfinite(cmd) & (cmd > 0)
    run.apply("values", "missing or non-positive voltage, acceleration or command", valid)
    table = _table(run, cols, rotors)
    report = FlightReport(
        flight=_flight_id(flight),
        path=flight.path,
        format=flight.format,
        duration_s=float(run.nbins * run.dt_s),
        kept_s=float(run.keep.sum() * run.dt_s),
        samples=int(run.keep.sum()),
        steps=run.steps,
        warnings=run.warnings,
        voltage_unknown=run.voltage_unknown,
    )
    meta: dict[str, Any] = {"mass_kg": run.mass_kg, "rotors": rotors, "sources": sources}
    if run.voltage_unknown is not None:
        meta["voltage_source"] = None
        meta["voltage_unknown"] = run.voltage_missing
    return table, meta, report


def _start(flight: FlightLog, opts: DfOptions, tmap: ThrustMap | None) -> FlightRun:
    """The flight's acceleration on a plausible timeline, in m/s², its bins, its mass and what
    is known of its voltage; refused when it has no acceleration or no mass."""
    if flight.accel_up_mps2 is None or not len(flight.accel_up_mps2):
        off = [w for w in flight.warnings if w.startswith("no accelerometer data")]
        if off:  # the reader saw an accelerometer that reads exactly zero: say that
            raise DataFormatError(f"{off[0]}: a Df needs it for F_m", file=flight.path)
        why = [w for w in flight.warnings if "acceler" in w or "IMU" in w]
        raise DataFormatError(
            "flight log has no upward acceleration: a Df needs it for F_m"
            + (f" ({'; '.join(why)})" if why else ""),
            file=flight.path,
        )
    voltage_missing = _voltage_missing(flight)
    voltage_unknown = (
        None
        if voltage_missing is None
        else f"battery voltage unknown ({voltage_missing}): the Df's voltage_v column is empty, "
        "so γ can only be fitted as a constant and the stand map's forward direction (which "
        "needs B) cannot give T_c from the motor outputs"
    )
    mass = opts.mass_kg if opts.mass_kg is not None else flight.metadata.get("mass_kg")
    if mass is None:
        raise ConfigError("give the vehicle mass (--mass-kg): the log does not record it")
    acc, time_warnings = plausible_timeline(flight.accel_up_mps2, opts.rate_hz, flight.path)
    # every reader's acceleration is questioned here, not only the CSV readers': in g it is
    # converted and said, one that cannot be a specific force is refused (issue 31 item 8),
    # after the ground-rest calibration below: only what that cannot explain (issue 34)
    acc, unit_notes = specific_force_unit(acc, landed=flight.landed)
    t0 = float(acc.time_s[0])
    nbins = max(1, int(np.ceil((float(acc.time_s[-1]) - t0) * opts.rate_hz)) + 1)
    warnings = [w for w in flight.warnings if voltage_unknown is None or w not in voltage_unknown]
    warnings += [*time_warnings, *unit_notes]
    if voltage_unknown is not None:
        warnings.append(voltage_unknown)
    return FlightRun(
        flight, opts, tmap, mass, acc, t0, nbins, voltage_missing, voltage_unknown, warnings
    )


def _signals(run: FlightRun) -> None:
    """a_up and the voltage on the bins (a_up smoothed), the bins with an accelerometer
    sample, the tilt; a slow accelerometer is warned about."""
    opts, acc = run.opts, run.acc
    a_up = run.rs(acc)
    volt = (
        run.rs(run.flight.voltage_v) if run.voltage_unknown is None else np.full(run.nbins, np.nan)
    )
    assert a_up is not None and volt is not None
    run.has_data = np.isfinite(a_up)  # a sample in the bin, or one within max_gap_s
    if opts.accel_smooth_s > 0:
        a_up = running_mean(a_up, int(round(opts.accel_smooth_s * opts.rate_hz)))
    run.a_up, run.volt = a_up, volt
    run.tilt = run.rs(run.flight.extras.get("tilt_deg"))
    span_s = float(acc.time_s[-1] - acc.time_s[0]) if len(acc) > 1 else 0.0
    acc_rate_hz = (len(acc) - 1) / span_s if span_s > 0 else 0.0
    if 0 < acc_rate_hz < MIN_ACCEL_RATE_HZ:
        run.warnings.append(
            f"upward acceleration logged at only {acc_rate_hz:.0f} Hz ({acc.origin}): vibration "
            "aliases into a_up, so F_m scatters; log the IMU faster for a tighter γ"
        )


def _log_pause(run: FlightRun) -> None:
    """Rule "log-pause": no message of any kind within max_gap_s is the log pausing, not a gap
    in the IMU: ArduCopter 3.2-3.3 write only while armed (motors.pde: init_disarm_motors
    logs DISARMED then DataFlash.EnableWrites(false); init_arm_motors start_logging()), PX4
    and others stop a log with the vehicle disarmed. Named apart from an accelerometer gap."""
    flight, opts = run.flight, run.opts
    paused = ~run.has_data
    for other in (flight.thrust_cmd_n, flight.thrust_cmd_norm, flight.motor_outputs,
                  flight.voltage_v):  # fmt: skip
        binned_other = run.rs(other) if other is not None and len(other) else None
        if binned_other is not None:
            fin = np.isfinite(binned_other)
            paused &= ~(fin if fin.ndim == 1 else fin.any(axis=1))
    run.apply("log-pause", f"the log pauses (no message within {opts.max_gap_s:g} s): logging "
              "stopped, e.g. disarmed (ArduCopter 3.2-3.3 log only while armed)", ~paused)  # fmt: skip


def _imu_data(run: FlightRun) -> None:
    run.apply(
        "data", f"no accelerometer sample within {run.opts.max_gap_s:g} s (IMU gap)", run.has_data
    )


def _armed(run: FlightRun) -> None:
    if run.flight.armed is not None:
        run.apply("armed", "disarmed", run.flight.armed.hold(run.centres) > 0.5)
    else:
        run.warnings.append("no armed state in the log: every sample taken as armed")


def _landed(run: FlightRun) -> None:
    landed = run.flight.landed
    if landed is not None:
        run.airborne = landed.hold(run.centres) < 0.5
        # the state's own origin: the log's land detector, or what rebuilt it (throttle-zero)
        run.apply("airborne", f"landed ({landed.origin})", run.airborne)
    else:
        run.warnings.append("no landed state in the log: airborne time judged by the filters alone")


def _command(run: FlightRun) -> None:
    """The command that tells steady flight (newtons, normalised, or the mean motor output in
    %), the same in %; a_up calibrated on the ground rest before takeoff and a specific force
    that cannot be physical refused."""
    flight = run.flight
    cmd = run.rs(flight.thrust_cmd_n) if flight.thrust_cmd_n is not None else None
    if cmd is None:
        cmd = run.rs(flight.thrust_cmd_norm)
    if cmd is None and flight.motor_outputs is not None:
        m = run.rs(flight.motor_outputs)
        if m is not None and flight.motor_output_scale is not None:
            m = flight.motor_output_scale.to_pct(m)
        cmd = None if m is None else (m.mean(axis=1) if m.ndim == 2 else m)
    cmd_pct = cmd
    if cmd_pct is not None and flight.thrust_cmd_n is None and flight.thrust_cmd_norm is not None:
        cmd_pct = cmd_pct * 100.0
    run.cmd_steady, run.cmd_pct = cmd, cmd_pct
    if cmd is not None:
        run.a_up = rest_calibration(
            run.a_up, run.rs(run.acc), cmd, run.tilt, run.opts, run.apply, run.warnings
        )
    calibrated = any(w.startswith("accelerometer calibrated at rest") for w in run.warnings)
    # judged in flight (where it is g), as its unit was: a ground stretch logged as zeros
    air = run.airborne
    flying = air if air.sum() >= max(10, 0.1 * run.nbins) else np.ones(run.nbins, bool)
    refuse_unphysical_specific_force(run.a_up[flying], run.acc.origin, flight.path,
                                     calibrated="its calibration at rest" if calibrated else "")  # fmt: skip


def _in_air(run: FlightRun) -> None:
    in_air_evidence(
        run,
        run.cmd_pct if run.flight.thrust_cmd_n is None else None,
        run.cmd_steady,
        run.a_up,
    )


def _settle(run: FlightRun) -> None:
    """Takeoff / landing transients: trim settle_s from both ends of every airborne run."""
    settled = np.zeros(run.nbins, bool)
    trim = int(round(run.opts.settle_s * run.opts.rate_hz))
    for a, b in mask_runs(run.keep):
        if b - a > 2 * trim:
            settled[a + trim : b - trim] = True
    run.apply("settle", f"within {run.opts.settle_s:g} s of takeoff or landing", settled)


def _climb(run: FlightRun) -> None:
    climb_rule(run.flight, run.rs, run.opts, run.apply, run.warnings)


def _hover(run: FlightRun) -> None:
    tol = run.opts.accel_tol_mps2
    run.apply(
        "hover",
        f"|a_up − g| > {tol:g} m/s² (not near hover)",
        np.abs(np.nan_to_num(run.a_up, nan=np.inf) - G0) <= tol,
    )


def _saturation(run: FlightRun) -> None:
    """A saturated command or motor output: thrust limited, not steady flight."""
    flight = run.flight
    sat = np.zeros(run.nbins, bool)
    sat_what = []
    norm_cmd = run.rs(flight.thrust_cmd_norm)
    if norm_cmd is not None:
        sat |= np.nan_to_num(norm_cmd, nan=0.0) >= SATURATED_NORM
        sat_what.append(f"normalised command ≥ {SATURATED_NORM:g}")
    if flight.motor_outputs is not None and flight.motor_output_scale is not None:
        binned_motors = run.rs(flight.motor_outputs)
        assert binned_motors is not None
        mpct = flight.motor_output_scale.to_pct(binned_motors)
        if mpct.ndim == 2 and mpct.shape[1] > 1:
            sat |= np.nan_to_num(mpct, nan=0.0).max(axis=1) >= SATURATED_NORM * 100.0
            sat_what.append(f"a motor output ≥ {SATURATED_NORM:.0%} of its range")
    if sat_what:
        run.apply(
            "saturation", " or ".join(sat_what) + " (thrust limited: not steady flight)", ~sat
        )


def _level(run: FlightRun) -> None:
    """The level of the bins that can enter the Df (a command of 0 never does: "values"):
    idle bins still kept (an armed wait no state signal placed on the ground) must not pull
    the median to 0, which then dropped every bin commanding thrust."""
    cmd, keep = run.cmd_steady, run.keep
    if cmd is None or not keep.any():
        return
    flying = keep & (np.nan_to_num(cmd) > 0)
    level = float(nanmedian(cmd[flying])) if flying.any() else float("nan")
    with np.errstate(invalid="ignore"):
        near = np.abs(cmd - level) <= 0.5 * abs(level)
    run.apply(
        "level",
        "command below half or above 1.5× the median of the kept bins commanding thrust "
        "(idle on the ground?)",
        near,
    )


def _steady(run: FlightRun) -> None:
    """A command off its running median, and the bins around every command step (the rotor
    answers within its lag; those bins hold a partial command and a_up is a centred mean)."""
    opts, cmd = run.opts, run.cmd_steady
    if cmd is None or not opts.steady_tol > 0:
        return
    window = int(round(opts.steady_window_s * opts.rate_hz))
    steady = steady_mask(cmd, window, opts.steady_tol)
    run.apply(
        "steady",
        f"command off its {opts.steady_window_s:g} s running median by > {opts.steady_tol:.0%}",
        steady,
    )
    lag = opts.rotor_lag_s + 0.5 * opts.accel_smooth_s + 1.0 / opts.rate_hz
    run.apply(
        "transient",
        f"within {lag:.2g} s of a command change > {opts.steady_tol:.0%} (rotor lag "
        f"{opts.rotor_lag_s:g} s, a_up smoothing, one bin)",
        ~dilate(~steady & np.isfinite(cmd), int(np.ceil(lag * opts.rate_hz))),
    )


def _tilt(run: FlightRun) -> None:
    if run.tilt is not None:
        run.apply(
            "tilt",
            f"tilt > {run.opts.tilt_max_deg:g}°",
            np.nan_to_num(run.tilt, nan=0.0) <= run.opts.tilt_max_deg,
        )


#: the filters, in order (each sees the bins the ones before it kept)
FILTERS: tuple[Callable[[FlightRun], None], ...] = (
    _log_pause,
    _imu_data,
    _armed,
    _landed,
    _command,
    _in_air,
    _settle,
    _climb,
    _hover,
    _saturation,
    _level,
    _steady,
    _tilt,
)


def _columns(run: FlightRun) -> tuple[dict[str, FloatArray], dict[str, Any], int | None]:
    """The Df's columns on the bins (voltage, a_up, F_m, the motor outputs in %, the thrust
    command), where each came from, and the rotor count."""
    flight, opts = run.flight, run.opts
    sources: dict[str, Any] = {
        "time_s": f"bin centres at {opts.rate_hz:g} Hz, from the first accelerometer sample",
        "voltage_v": None if flight.voltage_v is None else flight.voltage_v.origin,
        "accel_up_mps2": run.acc.origin
        + f" (bin mean at {opts.rate_hz:g} Hz, centred {opts.accel_smooth_s:g} s running mean)",
        "force_n": f"mass_kg × accel_up_mps2, collective (mass {run.mass_kg:g} kg)",
    }
    cols: dict[str, FloatArray] = {
        "voltage_v": run.volt,
        "accel_up_mps2": run.a_up,
        "force_n": run.mass_kg * run.a_up,
    }
    motors = run.rs(flight.motor_outputs)
    rotors = opts.rotors
    collective_motor = bool(flight.metadata.get("motor_outputs_collective"))
    if motors is not None and motors.ndim == 2 and rotors is None and not collective_motor:
        rotors = motors.shape[1]
    if motors is not None and flight.motor_output_scale is not None:
        _motor_columns(run, motors, cols, sources)
    norm = run.rs(flight.thrust_cmd_norm)
    if norm is not None:
        cols["thrust_cmd_norm"] = norm
        sources["thrust_cmd_norm"] = flight.thrust_cmd_norm.origin if flight.thrust_cmd_norm else ""
    _thrust_command(run, (motors, norm), rotors, cols, sources)
    if "throttle_pct" not in cols and motors is not None and flight.motor_output_scale is not None:
        cols["throttle_pct"] = flight.motor_output_scale.to_pct(motors).mean(axis=1)
        sources["throttle_pct"] = "mean motor output, % of the log's own scale"
    hover = flight.hover_thrust_estimate or flight.extras.get("hover_throttle")
    if hover is not None:
        cols["hover_thrust_est"] = bin_mean(hover, run.t0, opts.rate_hz, run.nbins, opts.max_gap_s)
        sources["hover_thrust_est"] = hover.origin
    return cols, sources, rotors


def _motor_columns(
    run: FlightRun, motors: FloatArray, cols: dict[str, FloatArray], sources: dict[str, Any]
) -> None:
    """Each motor output in % of its scale, and where the outputs and their scale came from."""
    flight = run.flight
    sc = flight.motor_output_scale
    assert sc is not None
    pct = sc.to_pct(motors)
    for i in range(pct.shape[1]):
        cols[f"motor{i}_pct"] = pct[:, i]
    sources["motor_pct"] = (
        f"{flight.motor_outputs.origin if flight.motor_outputs else ''} as % of "
        f"{sc.name} {sc.lo:g}..{sc.hi:g} {sc.unit}"
    )
    sources["motor_output_scale"] = sc.to_dict()
    sources["motor_output_scale_source"] = flight.metadata.get(
        "motor_output_scale_source", "not stated by the reader"
    )
    if "motor_channels" in flight.metadata:
        sources["motor_channels"] = flight.metadata["motor_channels"]


def _thrust_command(
    run: FlightRun,
    commands: tuple[FloatArray | None, FloatArray | None],
    rotors: int | None,
    cols: dict[str, FloatArray],
    sources: dict[str, Any],
) -> None:
    """T_c in newtons: from the log, else the motor outputs (or the normalised command)
    through the stand map's forward direction (``--thrust-source`` decides which may be used)."""
    flight, tmap, src = run.flight, run.tmap, run.opts.thrust_source
    motors, norm = commands
    t_cmd: FloatArray | None = None
    if flight.thrust_cmd_n is not None and src in ("auto", "log"):
        t_cmd = run.rs(flight.thrust_cmd_n)
        sources["thrust_cmd_n"] = flight.thrust_cmd_n.origin + " (collective, from the log)"
    elif src == "log":
        raise DataFormatError("the log has no thrust command in newtons", file=flight.path)
    needs_b = tmap is not None and (
        (src in ("auto", "motors") and motors is not None) or (src == "norm" and norm is not None)
    )
    if t_cmd is None and needs_b and run.voltage_unknown is not None:
        raise DataFormatError(
            "T_c must come from the motor outputs through the stand map, whose forward direction "
            f"needs the battery voltage, and the log has none ({run.voltage_missing}); extract "
            "without --map",
            file=flight.path,
        )
    if t_cmd is None and tmap is not None and src in ("auto", "motors") and motors is not None:
        assert flight.motor_output_scale is not None
        if rotors is None:
            raise ConfigError("give the rotor count (--rotors): the log has one throttle column")
        mp, how = motor_pct_in_map_scale(
            flight.motor_output_scale.to_pct(motors),
            flight.motor_output_scale,
            tmap.throttle_scale,
        )
        t_cmd = thrust_from_motors(mp, run.volt, tmap, rotors)
        cols["throttle_pct"] = mp.mean(axis=1)
        sources["throttle_pct"] = f"mean motor output, % of the map's scale ({how})"
        sources["thrust_cmd_n"] = (
            f"motor outputs through the stand map's forward direction, per rotor, summed over "
            f"{rotors} rotors ({how})"
        )
    if t_cmd is None and tmap is not None and src in ("auto", "norm") and norm is not None:
        if rotors is None:
            raise ConfigError("give the rotor count (--rotors) to turn the command into newtons")
        t_cmd = rotors * tmap.thrust_n(norm * 100.0, run.volt, corrected=False)
        cols["throttle_pct"] = norm * 100.0
        sources["thrust_cmd_n"] = (
            f"normalised collective command × 100 % of the map's scale through its forward "
            f"direction, × {rotors} rotors (assumes every motor gets the collective command)"
        )
    if t_cmd is not None:
        cols["thrust_cmd_n"] = t_cmd
    elif norm is None and motors is None:
        raise DataFormatError(
            "flight log has no thrust command (newtons, normalised or motor outputs)",
            file=flight.path,
        )
    else:
        run.warnings.append("no map given: T_c in newtons not computed (thrust_cmd_norm only)")


def _table(run: FlightRun, cols: dict[str, FloatArray], rotors: int | None) -> Columns:
    """The kept bins as the Df's columns; warnings for thrust beyond the map and for a Df
    too short for a γ fit."""
    keep, n = run.keep, int(run.keep.sum())
    table: Columns = {"flight": np.full(n, _flight_id(run.flight), dtype=object),
                      "time_s": run.centres[keep]}  # fmt: skip
    for k, v in cols.items():
        table[k] = np.asarray(v, float)[keep]
    if run.tmap is not None and n and rotors:
        run.warnings.extend(
            map_extrapolation(
                run.tmap,
                table["voltage_v"],
                table["force_n"] / rotors,
                "per-rotor thrust (F_m / rotors)",
            )
        )
    if n < MIN_DF_SAMPLES:
        worst = sorted((st for st in run.steps if st.dropped_s > 0), key=lambda st: -st.dropped_s)
        run.warnings.append(
            f"only {n} samples of steady flight (fewer than {MIN_DF_SAMPLES}): too "
            "short for a γ fit; most time dropped by "
            + ", ".join(f"{st.name} {st.dropped_s:.1f} s ({st.reason})" for st in worst[:3])
        )
    return table


#: the reason the blackbox reader gives for a log with no data frames (blackbox.EMPTY_LOG)
EMPTY_LOG = "empty (no data frames)"


def _too_short(flight: FlightLog, opts: DfOptions) -> str | None:
    """Why one log of a multi-log file is too short to give a Df sample (None when it is not):
    the settle rule trims settle_s from both ends of every airborne run."""
    acc = flight.accel_up_mps2
    if acc is None or len(acc) < 2:
        return None  # extract_flight_columns names what is missing
    span_s = float(acc.time_s[-1] - acc.time_s[0])
    if span_s > 2.0 * opts.settle_s:
        return None
    return (
        f"too short: {span_s:.1f} s of data, a Df sample needs more than 2 × settle "
        f"({2.0 * opts.settle_s:g} s)"
    )


def _refusal(flight: FlightLog, why: str) -> dict[str, Any]:
    """One unusable log of a multi-log file, numbered as Betaflight's viewer numbers them."""
    return {
        "flight": _flight_id(flight),
        "path": flight.path,
        "log": flight.index + 1,
        "logs_in_file": int(flight.metadata.get("logs_in_file", 1)),
        "reason": why,
    }


def extract(flights: list[FlightLog], opts: DfOptions, tmap: ThrustMap | None = None) -> Df:
    """Df from every flight; each keeps its own id in the ``flight`` column.

    A flight from a file holding several logs (a flash dump) that cannot be used (no or an
    unphysical accelerometer, too short, anything else the rules refuse) is skipped and listed
    in the sidecar's ``refused`` (with the logs the reader could not decode); the others are
    extracted. Only when no log at all is left is the extraction refused, naming each log.
    A single-log file's refusal is raised as it is."""
    tables: list[Columns] = []
    reports = []
    sources: dict[str, Any] = {}
    per_flight: dict[str, Any] = {}
    refused: list[dict[str, Any]] = []
    seen_paths: set[str] = set()
    for fl in flights:
        if fl.path not in seen_paths:
            seen_paths.add(fl.path)
            for r in fl.metadata.get("logs_refused_by_reader", []):
                refused.append({"flight": f"{Path(fl.path).name}#{int(r['log']) - 1}",
                                "path": fl.path, **r})  # fmt: skip
        multi = int(fl.metadata.get("logs_in_file", 1)) > 1
        try:
            short = _too_short(fl, opts) if multi else None
            if short is not None:
                raise DataFormatError(short, file=fl.path)
            table, meta, report = extract_flight_columns(fl, opts, tmap)
        except DataFormatError as exc:
            if not multi:
                raise
            refused.append(
                _refusal(fl, (f"column '{exc.column}': " if exc.column else "") + exc.message)
            )
            continue
        tables.append(table)
        reports.append(report)
        per_flight[report.flight] = meta
        for k, v in meta["sources"].items():
            sources.setdefault(k, v)
    side = {
        "format": DF_FORMAT,
        "version": 1,
        "thrust_meaning": "collective (all rotors), N; the stand map is per rotor",
        "columns": sources,
        "flights": per_flight,
        "options": asdict(opts),
        # the map T_c was computed with: `gamma fit` refuses another (fitting.df.pool)
        "map": None
        if tmap is None
        else {
            "model": tmap.model,
            "sha256": tmap.file_sha256,
            "bench_sha256": tmap.bench_sha256,
        },
        "reports": [r.to_dict() for r in reports],
    }
    if refused:
        refused.sort(key=lambda r: (str(r["path"]), int(r["log"])))
        side["refused"] = refused
    if not reports:
        raise NoUsableLog(refused)
    return Df(None, side, reports, columns=concat_columns(tables))


class NoUsableLog(DataFormatError):
    """Every log of the input was refused: ``refused`` says which and why (one line each)."""

    def __init__(self, refused: list[dict[str, Any]]) -> None:
        paths = sorted({str(r["path"]) for r in refused})
        lines = [ln.split(": ", 1)[1] if len(paths) == 1 else ln for ln in refusal_lines(refused)]
        super().__init__(
            f"none of its {len(refused)} log(s) could be used: "
            + "; ".join(lines[:3])
            + (f"; ... ({len(lines) - 3} more lines)" if len(lines) > 3 else ""),
            file=", ".join(paths),
        )
        self.refused = refused


def refusal_lines(refused: list[dict[str, Any]]) -> list[str]:
    """One line per refused log, except that a file's empty logs (flash chips hold dozens)
    share one line naming their numbers."""
    lines: list[str] = []
    empty: dict[str, list[dict[str, Any]]] = {}
    for r in refused:
        if r["reason"] == EMPTY_LOG:
            empty.setdefault(str(r["path"]), []).append(r)
        else:
            lines.append(refusal_line(r))
    for path, rs in empty.items():
        if len(rs) == 1:
            lines.append(refusal_line(rs[0]))
            continue
        nums = _ranges([int(r["log"]) for r in rs])
        lines.append(f"{path}: logs {nums} of {rs[0]['logs_in_file']} skipped: {EMPTY_LOG}")
    return lines


def _ranges(nums: list[int]) -> str:
    """1, 2, 3, 5 -> "1-3, 5"."""
    out: list[str] = []
    for n in sorted(set(nums)):
        if out and n == int(out[-1].split("-")[-1]) + 1:
            out[-1] = out[-1].split("-")[0] + f"-{n}"
        else:
            out.append(str(n))
    return ", ".join(out)


def refusal_line(r: dict[str, Any]) -> str:
    """One refused log in one line: its file, its number (1-based, as the viewer's) and why."""
    return f"{r['path']}: log {r['log']} of {r['logs_in_file']} skipped: {r['reason']}"
