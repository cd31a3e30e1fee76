"""CLI: ``flightlog inspect|extract`` and ``gamma fit`` (thin over thrustmap.fitting)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from thrustmap.cli.df_options import EXTRACT_FIELDS, df_click_options
from thrustmap.cli.textwidth import echo
from thrustmap.core.errors import ConfigError

if TYPE_CHECKING:  # numpy, pandas and the readers load only when a command runs
    from thrustmap.flightlogs.series import FlightLog, Signal

_FIELDS = (
    "voltage_v",
    "accel_up_mps2",
    "thrust_cmd_n",
    "thrust_cmd_norm",
    "motor_outputs",
    "armed",
    "landed",
    "hover_thrust_estimate",
)


def _signal_info(sig: Signal) -> dict[str, Any]:
    import numpy as np

    v = sig.values[np.isfinite(sig.values).all(axis=1)] if sig.values.ndim == 2 else sig.values
    v = v[np.isfinite(v)] if v.ndim == 1 else v
    dur = float(sig.time_s[-1] - sig.time_s[0]) if len(sig) > 1 else 0.0
    info: dict[str, Any] = {
        "origin": sig.origin,
        "unit": sig.unit,
        "samples": len(sig),
        "rate_hz": round((len(sig) - 1) / dur, 2) if dur > 0 else None,
    }
    if len(v):
        info["min"] = float(np.min(v))
        info["max"] = float(np.max(v))
        if sig.values.ndim == 2:
            info["columns"] = int(sig.values.shape[1])
    return info


def inspect_flight(flight: FlightLog) -> dict[str, Any]:
    """What a flight log holds: duration, fields found (origin, rate, range), airborne windows."""
    from thrustmap.fitting.df.airborne import airborne_windows

    fields = {
        name: _signal_info(sig)
        for name in _FIELDS
        if (sig := getattr(flight, name)) is not None and len(sig)
    }
    extras = {k: _signal_info(s) for k, s in flight.extras.items() if len(s)}
    times = [s.time_s for s in [getattr(flight, n) for n in _FIELDS] if s is not None and len(s)]
    start = min((float(t[0]) for t in times), default=0.0)
    end = max((float(t[-1]) for t in times), default=0.0)
    meta = {k: v for k, v in flight.metadata.items() if k not in ("params", "topics")}
    return {
        "path": flight.path,
        "format": flight.format,
        "index": flight.index,
        "duration_s": end - start,
        # the log's own time base, which the airborne windows are given in
        "start_s": start,
        "end_s": end,
        "fields": fields,
        "extras": extras,
        "missing": [n for n in _FIELDS if n not in fields],
        "motor_output_scale": None
        if flight.motor_output_scale is None
        else flight.motor_output_scale.to_dict(),
        "airborne_windows_s": [[round(a, 3), round(b, 3)] for a, b in airborne_windows(flight)],
        "metadata": meta,
        "topics": flight.metadata.get("topics"),
        "warnings": flight.warnings,
    }


@click.group("flightlog")
def flightlog_group() -> None:
    """Read flight logs (ULog, DataFlash, tlog, blackbox, rosbag, CSV) and extract Df."""


@flightlog_group.command("inspect")
@click.argument("logs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--format", "fmt", help="Reader name instead of content detection.")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
def inspect_cmd(logs: tuple[Path, ...], fmt: str | None, as_json: bool) -> None:
    """What is inside LOG: duration, fields found, airborne windows."""
    from thrustmap.flightlogs.detect import detect, read_log

    out = []
    for path in logs:
        reader = detect(path) if fmt is None else None
        for flight in read_log(path, format=fmt):
            info = inspect_flight(flight)
            info["reader"] = reader.name if reader else fmt
            out.append(info)
    if as_json:
        click.echo(json.dumps(out, indent=2, default=str))
        return
    for info in out:
        echo(f"{info['path']} [{info['reader']}, flight {info['index']}]")
        echo(
            f"  duration {info['duration_s']:.1f} s (log time {info['start_s']:.1f} .. "
            f"{info['end_s']:.1f} s; the airborne windows below are in log time too)"
        )
        for name, f in {**info["fields"], **info["extras"]}.items():
            rng = f" {f['min']:.4g}..{f['max']:.4g}" if "min" in f else ""
            rate = f" {f['rate_hz']} Hz" if f["rate_hz"] else ""
            echo(f"  {name:22s} {f['origin']} [{f['unit']}]{rate}{rng}")
        if info["missing"]:
            echo(f"  missing: {', '.join(info['missing'])}")
        wins = info["airborne_windows_s"]
        echo(
            f"  airborne windows (log time): {len(wins)}"
            + "".join(f"\n    {a:.1f} .. {b:.1f} s ({b - a:.1f} s)" for a, b in wins)
        )
        for w in info["warnings"]:
            echo(f"  warning: {w}")
    from thrustmap.fitting.df.extraction import refusal_lines

    skipped: dict[str, list[dict[str, Any]]] = {}  # the logs a reader skipped, once per file
    for info in out:
        for r in info["metadata"].get("logs_refused_by_reader") or []:
            entry = {"path": info["path"], **r}
            if entry not in skipped.setdefault(str(info["path"]), []):
                skipped[str(info["path"])].append(entry)
    for rs in skipped.values():
        for line in refusal_lines(rs):
            echo(f"not read: {line}")


@flightlog_group.command("readers")
def readers_cmd() -> None:
    """List the flight-log readers and whether they are usable here."""
    from thrustmap.flightlogs.detect import available

    for reader, why in available():
        state = "ok" if why is None else f"unavailable: {why}"
        echo(f"{reader.name:14s} {reader.description} ({state})")


@flightlog_group.command("extract")
@click.argument("logs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--map", "map_path", type=click.Path(path_type=Path), help="Stand map (per rotor).")
@click.option("-o", "--output", required=True, type=click.Path(path_type=Path), help="Df CSV.")
@df_click_options(EXTRACT_FIELDS)
@click.option("--format", "fmt", help="Reader name instead of content detection.")
@click.option(
    "--force",
    is_flag=True,
    help="Extract even when the map says the vehicle cannot hover at --mass-kg (said, and "
    "recorded in the Df sidecar).",
)
@click.option("--json", "as_json", is_flag=True, help="Print the filter report as JSON.")
def extract_cmd(
    logs: tuple[Path, ...],
    map_path: Path | None,
    output: Path,
    fmt: str | None,
    force: bool,
    as_json: bool,
    **df_values: Any,
) -> None:
    """Extract Df (steady near-hover samples) from LOG... into a CSV plus a JSON sidecar.

    With --map, a mass whose hover thrust the map puts outside its reach (0..100 % throttle)
    is refused (exit 2) unless --force."""
    from thrustmap.core.files import check_output_path
    from thrustmap.core.identity import Identity, file_sha256, refuse_repeats
    from thrustmap.fitting.df.dffile import sidecar_path, write_df
    from thrustmap.fitting.df.extraction import extract
    from thrustmap.fitting.df_options import DfOptions
    from thrustmap.flightlogs.detect import read_log

    inputs = [*logs, *([map_path] if map_path else [])]
    plan = check_output_path(output, inputs=inputs, what="Df output")
    side_plan = check_output_path(sidecar_path(output), inputs=inputs, what="Df sidecar")
    if side_plan.path.resolve() == plan.path.resolve():
        raise ConfigError(
            f"the Df output needs a name its sidecar ({side_plan.path.name}) does not share; "
            "use .csv",
            file=str(output),
        )
    opts = DfOptions(**df_values)
    tmap = None
    if map_path:  # the map module (models, version metadata) only when a map is given
        from thrustmap.fitting.mapfile import ThrustMap

        tmap = ThrustMap.load(map_path)
    from thrustmap.fitting.df.extraction import NoUsableLog, refusal_lines

    hashes = [(p, file_sha256(p)) for p in logs if p.is_file()]
    refuse_repeats((Identity(str(p), h) for p, h in hashes), "flight log")
    flights: list[FlightLog] = []
    for path in logs:
        flights.extend(read_log(path, format=fmt))
    try:
        df = extract(flights, opts, tmap)
    except NoUsableLog as exc:  # one line per refused log, then the error line (exit 2)
        for line in refusal_lines(exc.refused):
            echo(f"refused: {line}", err=True)
        raise
    if tmap is not None:
        # the pack first: on another motor's map, the mass's hover thrust means nothing
        why = _check_pack(df.table["voltage_v"], tmap, force, nothing="nothing written")
        _check_hover(df.sources, tmap, force)
        if why is not None:
            df.sources["forced"] = [*df.sources.get("forced", []), why]
    df.sources["logs"] = [{"path": str(p), "sha256": h} for p, h in hashes]
    if isinstance(df.sources.get("map"), dict):
        df.sources["map"]["path"] = str(map_path)
    side = write_df(df, output)
    refused = df.sources.get("refused", [])
    for line in refusal_lines(refused):  # the logs of a flash dump that could not be used
        echo(f"warning: {line}", err=True)
    for r in df.reports:
        if r.voltage_unknown is not None:
            echo(f"warning: {r.flight}: {r.voltage_unknown}", err=True)
    if not len(df):
        echo(
            "warning: no steady flight to extract (0 samples; too short for a Df), wrote an "
            "empty Df: " + "; ".join(_summary(r) for r in df.reports),
            err=True,
        )
    if as_json:  # the flights used (status "used") and the logs refused (status "refused")
        out = [{**r.to_dict(), "status": "used"} for r in df.reports]
        out += [{**ref, "status": "refused"} for ref in refused]
        click.echo(json.dumps(out, indent=2))
        return
    for r in df.reports:
        if len(df):  # an empty Df's summaries are in the warning above: said once
            echo(_summary(r))
        for w in r.warnings:
            # an empty Df's "only 0 samples ... most time dropped by ..." repeats its summary
            if w != r.voltage_unknown and not (not len(df) and w.startswith("only 0 samples")):
                echo(f"  warning: {w}")
    replaced = [str(x.path) for x in (plan, side_plan) if x.replaced]
    if refused:
        echo(f"used {len(df.reports)} log(s), refused {len(refused)} (listed in {side})")
    echo(
        f"wrote {len(df)} samples to {output} (sources in {side})"
        + (f"; replaced the previous {' and '.join(replaced)}" if replaced else "")
    )


def _check_pack(voltage_v: Any, tmap: Any, force: bool, *, nothing: str) -> str | None:
    """The flown battery's cell count against the map's (``ThrustMap.pack_refusal``):
    refused unless ``force``; a forced one is logged and returned, for the caller to record
    (``forced``)."""
    import logging

    why: str | None = tmap.pack_refusal(voltage_v)
    if why is None:
        return None
    if not force:
        raise ConfigError(f"--map: {why}; {nothing} (--force goes on anyway)")
    logging.getLogger("thrustmap.cli").warning("forced (--force), recorded: %s", why)
    return why


def _check_hover(side: dict[str, Any], tmap: Any, force: bool) -> None:
    """Each flight's mass against the map's reach (``ThrustMap.hover_refusal``): refused
    unless ``force``; a forced one is logged and recorded in the sidecar (``forced``)."""
    import logging

    forced = []
    for fid, meta in side.get("flights", {}).items():
        mass, rotors = meta.get("mass_kg"), meta.get("rotors")
        if not isinstance(mass, (int, float)) or not isinstance(rotors, int) or rotors < 1:
            continue
        why = tmap.hover_refusal(float(mass), rotors)
        if why is None:
            continue
        if not force:
            raise ConfigError(f"{fid}: {why}; nothing written (--force extracts anyway)")
        logging.getLogger("thrustmap.cli").warning(
            "%s: forced (--force), recorded in the Df sidecar: %s", fid, why
        )
        forced.append(f"{fid}: {why}")
    if forced:
        side["forced"] = forced


def _summary(r: Any) -> str:
    parts = [f"{s.name} −{s.dropped_s:.1f} s ({s.reason})" for s in r.steps if s.dropped_s > 0]
    return f"{r.flight}: kept {r.kept_s:.1f} of {r.duration_s:.1f} s" + (
        ": " + ", ".join(parts) if parts else ""
    )


@click.group("gamma")
def gamma_group() -> None:
    """The correction factor γ(B) from Df (seed paper eq. 9-11)."""


@gamma_group.command("fit")
@click.argument("dfs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--map", "map_path", required=True, type=click.Path(path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(path_type=Path))
@click.option("--loss", type=click.Choice(["l1", "l2"]), default="l1", show_default=True)
@click.option(
    "--degree",
    type=click.Choice(["auto", "0", "1", "2", "3"]),
    default="auto",
    show_default=True,
    help="Polynomial degree in B; auto = one-standard-error rule over held-out folds.",
)
@click.option("--rotors", type=int, help="Rotor count, when the Df sidecar lacks it.")
@click.option(
    "--pool-mixed",
    is_flag=True,
    help="Fit one γ(B) over flights with different mass or rotor count (refused otherwise).",
)
@click.option(
    "--force",
    is_flag=True,
    help="Write a γ(B) outside the physical band 0.5..2 or from a too-short Df anyway (said, "
    "and recorded in the map).",
)
@click.option("--json", "as_json", is_flag=True, help="Print the fit and metrics as JSON.")
def gamma_fit_cmd(
    dfs: tuple[Path, ...],
    map_path: Path,
    output: Path,
    loss: str,
    degree: str,
    rotors: int | None,
    pool_mixed: bool,
    force: bool,
    as_json: bool,
) -> None:
    """Fit γ(B) on DF... and write the map with its correction block.

    A γ outside 0.5..2 anywhere over the flown voltages, or a Df too short for a γ fit, is
    refused (exit 2) unless --force, which says so and records it in the map."""
    from thrustmap.core.files import atomic_write_text, check_output_path
    from thrustmap.fitting.df.dffile import sidecar_path
    from thrustmap.fitting.df.pool import pool_dfs
    from thrustmap.fitting.gamma import GammaOptions, check_physical, corrected_map, fit_gamma
    from thrustmap.fitting.mapfile import ThrustMap, file_sha256

    if rotors is not None and not 1 <= rotors <= 64:
        raise ConfigError(f"--rotors {rotors}: expected 1..64 rotors")
    inputs = [*dfs, *(sidecar_path(p) for p in dfs), map_path]
    plan = check_output_path(output, inputs=inputs, what="map output")
    tmap = ThrustMap.load(map_path)
    table, side = pool_dfs(dfs, tmap, str(map_path))  # repeats and another map refused
    pack = _check_pack(table["voltage_v"], tmap, force, nothing="nothing written")
    fit = fit_gamma(
        table,
        side,
        tmap,
        GammaOptions(
            loss="l1" if loss == "l1" else "l2",
            degree=None if degree == "auto" else int(degree),
        ),
        rotors=rotors,
        allow_mixed=pool_mixed,
    )
    sources = [{"path": str(p), "sha256": file_sha256(p)} for p in dfs]
    forced = check_physical(fit, force=force)  # refused unless --force (logged, recorded)
    forced = [*forced, *([pack] if pack else [])]
    out_map = corrected_map(tmap, fit, sources, forced=forced)
    atomic_write_text(output, out_map.dumps())
    if as_json:
        click.echo(json.dumps(fit.to_dict(), indent=2, default=float))
        return
    _print_fit(fit)
    _print_by_voltage(fit)
    _print_no_worse(fit)
    echo(f"wrote {output}" + (" (replaced the previous file)" if plan.replaced else ""))


def _print_fit(fit: Any) -> None:
    """γ(B), the flown voltage, the held-out error by degree and e_Th / e_T before and after."""
    from thrustmap.fitting.mapfile import gamma_text

    c = fit.correction
    terms = gamma_text(c.coefficients)
    echo(f"γ(B) = {terms}   (degree {fit.degree}, {fit.loss}, {fit.samples} samples)")
    flown = (
        "unknown (no battery voltage in the Df)"
        if fit.metrics.get("voltage_unknown")
        else f"{c.voltage_v.lo:.2f}..{c.voltage_v.hi:.2f} V"
    )
    echo(f"flown voltage {flown}; {fit.validation}")
    echo(
        "held-out error by degree (± standard error; the simplest within one SE of the best "
        "wins, among the degrees that leave no populated voltage bin worse than uncorrected): "
        + ", ".join(
            f"{d}: {e:.4g} ± {fit.heldout_se.get(d, float('nan')):.2g}"
            for d, e in sorted(fit.heldout.items())
        )
    )
    # fit.warnings were logged by the library (the CLI shows them on stderr): not echoed twice
    m = fit.metrics
    for key in ("e_Th", "e_T"):
        b, a = m.get(f"{key}_before_pct"), m.get(f"{key}_after_pct")
        if b and a:
            echo(
                f"{key} %: before {b['mean']:.3f} ± {b['std']:.3f}, after "
                f"{a['mean']:.3f} ± {a['std']:.3f}"
            )


def _print_by_voltage(fit: Any) -> None:
    """One row per voltage bin: n, γ, e_Th and e_T before/after, flagged when worse."""
    m = fit.metrics
    echo("by voltage:  V range        n    γ      e_Th before/after %   e_T before/after %")
    g = fit.guard
    floor = int(g.get("min_bin_samples", 20))
    worse_at = {tuple(w["voltage_v"]) for r in g.get("rejected", []) for w in r["worse"]}
    for row in m["by_voltage"]:
        lo, hi = row["voltage_v"]
        eth = (
            f"{row['e_Th_before_pct']['mean']:7.3f} / {row['e_Th_after_pct']['mean']:6.3f}"
            if "e_Th_before_pct" in row
            else " " * 16
        )
        key = "e_Th" if "e_Th_before_pct" in row else "e_T"
        flag = ""
        if row["samples"] < floor:
            flag = f"  (under {floor} samples: not checked)"
        elif row[f"{key}_after_pct"]["mean"] > row[f"{key}_before_pct"]["mean"]:
            flag = "  WORSE after γ"
        elif tuple(row["voltage_v"]) in worse_at:
            flag = "  (worse with the degree not used)"
        echo(
            f"  {lo:6.2f}..{hi:6.2f} {row['samples']:6d} {row['gamma']['mean']:6.4f}  {eth}"
            f"      {row['e_T_before_pct']['mean']:6.3f} / {row['e_T_after_pct']['mean']:6.3f}"
            + flag
        )


def _print_no_worse(fit: Any) -> None:
    """The no-worse check on stdout too (its warnings also went to stderr): which bin and why."""
    m, g = fit.metrics, fit.guard
    floor = int(g.get("min_bin_samples", 20))
    metric = g.get("metric", "e_Th")
    for r in g.get("rejected", []):
        bins = "; ".join(
            f"{w['voltage_v'][0]:.2f}..{w['voltage_v'][1]:.2f} V ({w['samples']} samples) "
            f"{w['before_pct']:.3f} → {w['after_pct']:.3f} %"
            for w in r["worse"]
        )
        echo(f"no-worse check: degree {r['degree']} makes {metric} worse at {bins}")
    if m["by_voltage"]:
        worse_now = [
            row
            for row in m["by_voltage"]
            if row["samples"] >= floor
            and row[f"{metric}_after_pct"]["mean"] > row[f"{metric}_before_pct"]["mean"]
        ]
        head = f"no-worse check ({metric}, bins with {floor}+ samples): "
        populated = [row for row in m["by_voltage"] if row["samples"] >= floor]
        if not populated:
            echo(
                head + f"no voltage bin has {floor}+ samples, so none could be judged: degree "
                f"{fit.degree} rests on held-out error alone (too little data per voltage)"
            )
        elif not fit.corrected:
            echo(head + "every γ(B) tried was worse somewhere: kept the uncorrected map (γ = 1)")
        elif worse_now:
            echo(head + f"the requested degree {fit.degree} is worse in the bins marked WORSE")
        else:
            echo(head + f"degree {fit.degree} kept, no populated bin worse than uncorrected")


def _register_live() -> None:  # `gamma live` lives in its own module (click only at import)
    from thrustmap.cli.gammalive import gamma_live_cmd

    gamma_group.add_command(gamma_live_cmd)


_register_live()
