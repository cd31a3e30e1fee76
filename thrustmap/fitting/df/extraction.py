"""The extraction: one flight's filters in order and its Df columns, and ``extract`` over
every flight (the sidecar naming each column's origin)."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from thrustmap.core.errors import ConfigError, DataFormatError
from thrustmap.fitting.df.airborne import climb_rule, in_air_evidence, rest_calibration
from thrustmap.fitting.df.options import (
    DF_FORMAT,
    G0,
    MIN_ACCEL_RATE_HZ,
    MIN_DF_SAMPLES,
    SATURATED_NORM,
    BoolArray,
    DfOptions,
    FilterStep,
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
from thrustmap.flightlogs.series import (
    FlightLog,
    FloatArray,
    Signal,
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
    """As ``extract_flight``, the table as columns of numpy arrays (no pandas needed)."""
    flight = select_motors(flight, opts.rotors)
    fid = _flight_id(flight)
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
    acc, unit_notes = specific_force_unit(acc)
    time_warnings = [*time_warnings, *unit_notes]
    t0 = float(acc.time_s[0])
    nbins = max(1, int(np.ceil((float(acc.time_s[-1]) - t0) * opts.rate_hz)) + 1)
    dt = 1.0 / opts.rate_hz
    centres: FloatArray = np.asarray(t0 + (np.arange(nbins) + 0.5) * dt, dtype=np.float64)

    binned: dict[int, FloatArray] = {}  # each signal is binned once (callers do not mutate)

    def rs(sig: Signal | None) -> FloatArray | None:
        if sig is None:
            return None
        if id(sig) not in binned:
            binned[id(sig)] = bin_mean(sig, t0, opts.rate_hz, nbins, opts.max_gap_s)
        return binned[id(sig)]

    a_up = rs(acc)
    volt = rs(flight.voltage_v) if voltage_unknown is None else np.full(nbins, np.nan)
    assert a_up is not None and volt is not None
    has_data = np.isfinite(a_up)  # a sample in the bin, or one within max_gap_s
    if opts.accel_smooth_s > 0:
        a_up = running_mean(a_up, int(round(opts.accel_smooth_s * opts.rate_hz)))
    tilt = rs(flight.extras.get("tilt_deg"))
    steps: list[FilterStep] = []
    duration = float(nbins * dt)
    keep = np.ones(nbins, bool)

    def apply(name: str, reason: str, ok: BoolArray) -> None:
        nonlocal keep
        before = keep.sum()
        keep = keep & ok
        steps.append(
            FilterStep(name, reason, float((before - keep.sum()) * dt), float(keep.sum() * dt))
        )

    warnings = [w for w in flight.warnings if voltage_unknown is None or w not in voltage_unknown]
    warnings += time_warnings
    if voltage_unknown is not None:
        warnings.append(voltage_unknown)
    span_s = float(acc.time_s[-1] - acc.time_s[0]) if len(acc) > 1 else 0.0
    acc_rate_hz = (len(acc) - 1) / span_s if span_s > 0 else 0.0
    if 0 < acc_rate_hz < MIN_ACCEL_RATE_HZ:
        warnings.append(
            f"upward acceleration logged at only {acc_rate_hz:.0f} Hz ({acc.origin}): vibration "
            "aliases into a_up, so F_m scatters; log the IMU faster for a tighter γ"
        )
    # Rule "log-pause": no message of any kind within max_gap_s is the log pausing, not a gap
    # in the IMU: ArduCopter 3.2-3.3 write only while armed (motors.pde: init_disarm_motors
    # logs DISARMED then DataFlash.EnableWrites(false); init_arm_motors start_logging()), PX4
    # and others stop a log with the vehicle disarmed. Named apart from an accelerometer gap.
    paused = ~has_data
    for other in (flight.thrust_cmd_n, flight.thrust_cmd_norm, flight.motor_outputs,
                  flight.voltage_v):  # fmt: skip
        binned_other = rs(other) if other is not None and len(other) else None
        if binned_other is not None:
            fin = np.isfinite(binned_other)
            paused &= ~(fin if fin.ndim == 1 else fin.any(axis=1))
    apply("log-pause", f"the log pauses (no message within {opts.max_gap_s:g} s): logging "
          "stopped, e.g. disarmed (ArduCopter 3.2-3.3 log only while armed)", ~paused)  # fmt: skip
    apply("data", f"no accelerometer sample within {opts.max_gap_s:g} s (IMU gap)", has_data)
    if flight.armed is not None:
        apply("armed", "disarmed", flight.armed.hold(centres) > 0.5)
    else:
        warnings.append("no armed state in the log: every sample taken as armed")
    if flight.landed is not None:
        airborne = flight.landed.hold(centres) < 0.5
        # the state's own origin: the log's land detector, or what rebuilt it (throttle-zero)
        apply("airborne", f"landed ({flight.landed.origin})", airborne)
    else:
        airborne = np.ones(nbins, bool)
        warnings.append("no landed state in the log: airborne time judged by the filters alone")
    cmd_for_steady = rs(flight.thrust_cmd_n) if flight.thrust_cmd_n is not None else None
    if cmd_for_steady is None:
        cmd_for_steady = rs(flight.thrust_cmd_norm)
    if cmd_for_steady is None and flight.motor_outputs is not None:
        m = rs(flight.motor_outputs)
        if m is not None and flight.motor_output_scale is not None:
            m = flight.motor_output_scale.to_pct(m)
        cmd_for_steady = None if m is None else (m.mean(axis=1) if m.ndim == 2 else m)
    cmd_pct = cmd_for_steady
    if cmd_pct is not None and flight.thrust_cmd_n is None and flight.thrust_cmd_norm is not None:
        cmd_pct = cmd_pct * 100.0
    if cmd_for_steady is not None:
        a_up = rest_calibration(a_up, rs(acc), cmd_for_steady, tilt, opts, apply, warnings)
    calibrated = any(w.startswith("accelerometer calibrated at rest") for w in warnings)
    refuse_unphysical_specific_force(a_up, acc.origin, flight.path,
                                     calibrated="its calibration at rest" if calibrated else "")  # fmt: skip
    in_air_evidence(
        flight, centres, rs, opts, apply, warnings,
        cmd_pct if flight.thrust_cmd_n is None else None, cmd_for_steady, a_up,
    )  # fmt: skip
    # takeoff / landing transients: trim settle_s from both ends of every airborne run
    settled = np.zeros(nbins, bool)
    trim = int(round(opts.settle_s * opts.rate_hz))
    for a, b in mask_runs(keep):
        if b - a > 2 * trim:
            settled[a + trim : b - trim] = True
    apply("settle", f"within {opts.settle_s:g} s of takeoff or landing", settled)
    climb_rule(flight, rs, opts, apply, warnings)
    apply(
        "hover",
        f"|a_up − g| > {opts.accel_tol_mps2:g} m/s² (not near hover)",
        np.abs(np.nan_to_num(a_up, nan=np.inf) - G0) <= opts.accel_tol_mps2,
    )
    sat = np.zeros(nbins, bool)
    sat_what = []
    norm_cmd = rs(flight.thrust_cmd_norm)
    if norm_cmd is not None:
        sat |= np.nan_to_num(norm_cmd, nan=0.0) >= SATURATED_NORM
        sat_what.append(f"normalised command ≥ {SATURATED_NORM:g}")
    if flight.motor_outputs is not None and flight.motor_output_scale is not None:
        binned_motors = rs(flight.motor_outputs)
        assert binned_motors is not None
        mpct = flight.motor_output_scale.to_pct(binned_motors)
        if mpct.ndim == 2 and mpct.shape[1] > 1:
            sat |= np.nan_to_num(mpct, nan=0.0).max(axis=1) >= SATURATED_NORM * 100.0
            sat_what.append(f"a motor output ≥ {SATURATED_NORM:.0%} of its range")
    if sat_what:
        apply("saturation", " or ".join(sat_what) + " (thrust limited: not steady flight)", ~sat)
    # the level of the bins that can enter the Df (a command of 0 never does: "values"):
    # idle bins still kept (an armed wait no state signal placed on the ground) must not
    # pull the median to 0, which then dropped every bin commanding thrust
    flying = keep if cmd_for_steady is None else keep & (np.nan_to_num(cmd_for_steady) > 0)
    if cmd_for_steady is not None and keep.any():
        level = float(nanmedian(cmd_for_steady[flying])) if flying.any() else float("nan")
        with np.errstate(invalid="ignore"):
            near = np.abs(cmd_for_steady - level) <= 0.5 * abs(level)
        apply(
            "level",
            "command below half or above 1.5× the median of the kept bins commanding thrust "
            "(idle on the ground?)",
            near,
        )
    if cmd_for_steady is not None and opts.steady_tol > 0:
        window = int(round(opts.steady_window_s * opts.rate_hz))
        steady = steady_mask(cmd_for_steady, window, opts.steady_tol)
        apply(
            "steady",
            f"command off its {opts.steady_window_s:g} s running median by > {opts.steady_tol:.0%}",
            steady,
        )
        # the rotor answers a command step within its lag; the bins straddling the step hold a
        # partial command and a_up is a centred running mean: drop those around every change
        lag = opts.rotor_lag_s + 0.5 * opts.accel_smooth_s + 1.0 / opts.rate_hz
        apply(
            "transient",
            f"within {lag:.2g} s of a command change > {opts.steady_tol:.0%} (rotor lag "
            f"{opts.rotor_lag_s:g} s, a_up smoothing, one bin)",
            ~dilate(~steady & np.isfinite(cmd_for_steady), int(np.ceil(lag * opts.rate_hz))),
        )
    if tilt is not None:
        apply(
            "tilt",
            f"tilt > {opts.tilt_max_deg:g}°",
            np.nan_to_num(tilt, nan=0.0) <= opts.tilt_max_deg,
        )

    sources: dict[str, Any] = {
        "time_s": f"bin centres at {opts.rate_hz:g} Hz, from the first accelerometer sample",
        "voltage_v": None if flight.voltage_v is None else flight.voltage_v.origin,
        "accel_up_mps2": acc.origin
        + f" (bin mean at {opts.rate_hz:g} Hz, centred {opts.accel_smooth_s:g} s running mean)",
        "force_n": f"mass_kg × accel_up_mps2, collective (mass {mass:g} kg)",
    }
    cols: dict[str, FloatArray] = {"voltage_v": volt, "accel_up_mps2": a_up, "force_n": mass * a_up}
    # thrust command
    motors = rs(flight.motor_outputs)
    rotors = opts.rotors
    collective_motor = bool(flight.metadata.get("motor_outputs_collective"))
    if motors is not None and motors.ndim == 2 and rotors is None and not collective_motor:
        rotors = motors.shape[1]
    if motors is not None and flight.motor_output_scale is not None:
        pct = flight.motor_output_scale.to_pct(motors)
        for i in range(pct.shape[1]):
            cols[f"motor{i}_pct"] = pct[:, i]
        sc = flight.motor_output_scale
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
    norm = rs(flight.thrust_cmd_norm)
    if norm is not None:
        cols["thrust_cmd_norm"] = norm
        sources["thrust_cmd_norm"] = flight.thrust_cmd_norm.origin if flight.thrust_cmd_norm else ""
    src = opts.thrust_source
    t_cmd: FloatArray | None = None
    if flight.thrust_cmd_n is not None and src in ("auto", "log"):
        t_cmd = rs(flight.thrust_cmd_n)
        sources["thrust_cmd_n"] = flight.thrust_cmd_n.origin + " (collective, from the log)"
    elif src == "log":
        raise DataFormatError("the log has no thrust command in newtons", file=flight.path)
    needs_b = tmap is not None and (
        (src in ("auto", "motors") and motors is not None) or (src == "norm" and norm is not None)
    )
    if t_cmd is None and needs_b and voltage_unknown is not None:
        raise DataFormatError(
            "T_c must come from the motor outputs through the stand map, whose forward direction "
            f"needs the battery voltage, and the log has none ({voltage_missing}); extract "
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
        t_cmd = thrust_from_motors(mp, volt, tmap, rotors)
        cols["throttle_pct"] = mp.mean(axis=1)
        sources["throttle_pct"] = f"mean motor output, % of the map's scale ({how})"
        sources["thrust_cmd_n"] = (
            f"motor outputs through the stand map's forward direction, per rotor, summed over "
            f"{rotors} rotors ({how})"
        )
    if t_cmd is None and tmap is not None and src in ("auto", "norm") and norm is not None:
        if rotors is None:
            raise ConfigError("give the rotor count (--rotors) to turn the command into newtons")
        t_cmd = rotors * tmap.thrust_n(norm * 100.0, volt, corrected=False)
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
        warnings.append("no map given: T_c in newtons not computed (thrust_cmd_norm only)")
    if "throttle_pct" not in cols and motors is not None and flight.motor_output_scale is not None:
        cols["throttle_pct"] = flight.motor_output_scale.to_pct(motors).mean(axis=1)
        sources["throttle_pct"] = "mean motor output, % of the log's own scale"
    hover = flight.hover_thrust_estimate or flight.extras.get("hover_throttle")
    if hover is not None:
        cols["hover_thrust_est"] = bin_mean(hover, t0, opts.rate_hz, nbins, opts.max_gap_s)
        sources["hover_thrust_est"] = hover.origin
    valid = np.isfinite(a_up) & (a_up > 0)
    if voltage_unknown is None:
        valid &= np.isfinite(volt) & (volt > 0)
    cmd = cols.get("thrust_cmd_n", cols.get("thrust_cmd_norm", cols.get("throttle_pct")))
    if cmd is not None:
        valid &= np.isfinite(cmd) & (cmd > 0)
    apply("values", "missing or non-positive voltage, acceleration or command", valid)
    table: Columns = {"flight": np.full(int(keep.sum()), fid, dtype=object),
                      "time_s": centres[keep]}  # fmt: skip
    for k, v in cols.items():
        table[k] = np.asarray(v, float)[keep]
    if tmap is not None and int(keep.sum()) and rotors:
        warnings.extend(
            map_extrapolation(
                tmap,
                table["voltage_v"],
                table["force_n"] / rotors,
                "per-rotor thrust (F_m / rotors)",
            )
        )
    if int(keep.sum()) < MIN_DF_SAMPLES:
        worst = sorted((st for st in steps if st.dropped_s > 0), key=lambda st: -st.dropped_s)
        warnings.append(
            f"only {int(keep.sum())} samples of steady flight (fewer than {MIN_DF_SAMPLES}): too "
            "short for a γ fit; most time dropped by "
            + ", ".join(f"{st.name} {st.dropped_s:.1f} s ({st.reason})" for st in worst[:3])
        )
    report = FlightReport(
        flight=fid,
        path=flight.path,
        format=flight.format,
        duration_s=duration,
        kept_s=float(keep.sum() * dt),
        samples=int(keep.sum()),
        steps=steps,
        warnings=warnings,
        voltage_unknown=voltage_unknown,
    )
    meta: dict[str, Any] = {"mass_kg": mass, "rotors": rotors, "sources": sources}
    if voltage_unknown is not None:
        meta["voltage_source"] = None
        meta["voltage_unknown"] = voltage_missing
    return table, meta, report


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
        "map": None if tmap is None else {"model": tmap.model, "sha256": tmap.file_sha256},
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
