"""CLI: models, fit, compare, evaluate, predict, inspect (thin over thrustmap.fitting)."""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import click

from thrustmap.cli.textwidth import echo, plural, table
from thrustmap.core import physical
from thrustmap.core.errors import ConfigError
from thrustmap.core.units import SCALES, ThrottleScale, parse_range, scale
from thrustmap.fitting.names import DEFAULT_MODEL, LOSSES, MODEL_NAMES, VALIDATIONS

if TYPE_CHECKING:  # the fitting machinery (numpy, scipy) is imported by the command that runs
    from thrustmap.fitting.fit.validation import Row
    from thrustmap.fitting.loaders.load import ColumnMap
    from thrustmap.fitting.selection.options import Selection

F = TypeVar("F", bound=Callable[..., Any])


def selection_options(f: F) -> F:
    """Options shared by fit, compare and evaluate."""
    opts = [
        click.option(
            "--throttle-range",
            metavar="LO:HI",
            help="Keep LO < throttle < HI (native units, e.g. µs).",
        ),
        click.option("--voltage-range", metavar="LO:HI", help="Keep LO < voltage < HI (V)."),
        click.option(
            "--thrust-range", metavar="LO:HI", help="Keep LO < thrust < HI (N, pulling positive)."
        ),
        click.option(
            "--all-samples",
            is_flag=True,
            help="Fit every sample (the paper's method) instead of steady-state points.",
        ),
        click.option(
            "--keep-past-top",
            is_flag=True,
            help="Keep points past the top of a file's thrust curve (an ESC saturating or "
            "cutting back: thrust no longer rising with the command).",
        ),
        click.option(
            "--col-throttle",
            metavar="NAME",
            help="Column map: throttle column (for CSVs no format matches).",
        ),
        click.option("--col-thrust", metavar="NAME", help="Column map: thrust column."),
        click.option("--col-voltage", metavar="NAME", help="Column map: voltage column."),
        click.option("--col-time", metavar="NAME", help="Column map: time column (s), optional."),
        click.option(
            "--thrust-unit",
            default="N",
            show_default=True,
            help="Column map: unit of the thrust column (N, kgf, gf, lbf).",
        ),
        click.option(
            "--throttle-scale",
            default="pwm",
            show_default=True,
            help=f"Column map: throttle scale name ({', '.join(SCALES)}) or LO:HI.",
        ),
    ]
    for opt in reversed(opts):
        f = opt(f)
    return f


def _selection(kw: dict[str, Any]) -> Selection:
    from thrustmap.fitting.selection.options import Selection

    def rng(key: str, what: str) -> tuple[float, float] | None:
        v = kw.get(key)
        return None if v is None else parse_range(v, what)

    return Selection(
        throttle_range=rng("throttle_range", "--throttle-range"),
        voltage_range=rng("voltage_range", "--voltage-range"),
        thrust_range=rng("thrust_range", "--thrust-range"),
        all_samples=bool(kw.get("all_samples")),
        keep_past_top=bool(kw.get("keep_past_top")),
    )


def _column_map(kw: dict[str, Any]) -> ColumnMap | None:
    from thrustmap.fitting.loaders.load import ColumnMap

    cols = [kw.get("col_throttle"), kw.get("col_thrust"), kw.get("col_voltage")]
    if not any(cols):
        for key, option in (
            ("throttle_scale", "--throttle-scale"),
            ("thrust_unit", "--thrust-unit"),
        ):
            if _given(key):  # an option that would change nothing is not silently dropped
                raise ConfigError(
                    f"{option} {kw[key]}: applies only with a column map (--col-throttle, "
                    "--col-thrust, --col-voltage); a recognised stand log names its own units"
                )
        return None
    if not all(cols):
        raise ConfigError(
            "a column map needs --col-throttle, --col-thrust and --col-voltage together"
        )
    text = kw.get("throttle_scale") or "pwm"
    if ":" in text:
        lo, hi = parse_range(text, "--throttle-scale")
        tscale = ThrottleScale("custom", lo, hi, "native")
    else:
        tscale = scale(text)
    return ColumnMap(
        throttle=str(cols[0]),
        thrust=str(cols[1]),
        voltage=str(cols[2]),
        time=kw.get("col_time"),
        thrust_unit=kw.get("thrust_unit") or "N",
        throttle_scale=tscale,
    )


def _given(name: str) -> bool:
    """True when option ``name`` was typed (not its default)."""
    ctx = click.get_current_context(silent=True)
    source = ctx.get_parameter_source(name) if ctx is not None else None
    return source is not None and source.name not in ("DEFAULT", "DEFAULT_MAP")


def _rows_table(rows: list[Row]) -> str:
    """Every evaluated point is the headline (n, mean, std, p95, max); the split into points
    inside and outside the training points' supported region is the detail beside it, and the
    share of them the map's 95 % interval held. A table wider than the terminal is printed one
    block per row (see textwidth.table); a model that could not be fitted says why."""

    def split(n: int, mean_pct: float) -> str:
        return f"n={n}, mean {mean_pct:.3f} %" if n else "n=0"

    def num(x: float) -> str:
        return f"{x:.3f}" if math.isfinite(x) else "-"

    def held(r: Row) -> str:
        if r.coverage_inside is None or r.coverage_outside is None:
            return "-"
        cells = [
            f"{where} {c.coverage_pct:.1f} % (±{c.median_half_width_pct:.2f} %)"
            for where, c in (("in", r.coverage_inside), ("out", r.coverage_outside))
            if c.n
        ]
        return ", ".join(cells) or "-"

    head = ["model", "validation", "n", "mean %", "std %", "p95 %", "max %"]
    head += ["inside supported region", "outside it"]
    with_coverage = any(r.coverage_inside is not None for r in rows)
    if with_coverage:
        head.append("interval held")
    body = []
    for r in rows:
        if r.error:  # the model could not be fitted: its row says why
            row = [r.model, r.validation, "0", "-", "-", "-", "-", f"not fitted: {r.error}", "-"]
        else:
            row = [
                r.model,
                r.validation,
                str(r.all.n),
                num(r.all.mean_pct),
                num(r.all.std_pct),
                num(r.all.p95_pct),
                num(r.all.max_pct),
                split(r.inside.n, r.inside.mean_pct),
                split(r.outside.n, r.outside.mean_pct),
            ]
        if with_coverage:
            row.append("-" if r.error else held(r))
        body.append(row)
    right = [False, False, True, True, True, True, True, False, False] + [False] * with_coverage
    lines = [table(head, body, right=right)]
    kinds = {r.validation.split(":", 1)[0] for r in rows}
    if kinds == {"evaluate"}:
        lines.append(
            "(every point of the new data; the split by the map's supported region beside them)"
        )
    elif kinds == {"in-sample"}:
        lines.append("(in-sample: every fitted point, scored by the map fitted on it)")
    elif "in-sample" in kinds:
        lines.append(
            "(in-sample rows: the fitted points themselves; other rows: all held-out points; "
            "the split by the supported region beside them)"
        )
    else:
        lines.append("(all held-out points; the split by the supported region beside them)")
    if any(r.coverage_inside is not None for r in rows):
        lines.append(
            "(interval held: the share of those points inside the map's 95 % prediction "
            "interval, in and out of its supported region, and the interval's median half-width)"
        )
    return "\n".join(lines)


def _meta_value(key: str, value: Any) -> str:
    """A sidecar value as a person reads it: an outcome is "completed" or "aborted: reason"."""
    if key == "outcome" and isinstance(value, dict):
        status = str(value.get("status") or "unknown")
        reason = str(value.get("reason") or "")
        return f"{status}: {reason}" if reason else status
    if isinstance(value, dict):
        return ", ".join(f"{k}={v}" for k, v in value.items())
    return str(value)


def _json(obj: Any) -> str:
    """JSON for --json output: NaN/inf become null, never bare NaN tokens."""
    from thrustmap.fitting.mapfile import json_ready

    return json.dumps(json_ready(obj), indent=2, allow_nan=False)


@click.command("models")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
def models_cmd(as_json: bool) -> None:
    """List every thrust-map model with its formula."""
    from thrustmap.fitting.models import MODELS

    if as_json:
        click.echo(
            json.dumps(
                [
                    {
                        "name": m.name,
                        "formula": m.formula,
                        "description": m.description,
                        "uses_voltage": m.uses_voltage,
                        "default": m.name == DEFAULT_MODEL,
                    }
                    for m in MODELS.values()
                ],
                indent=2,
            )
        )
        return
    for m in MODELS.values():
        mark = " (default)" if m.name == DEFAULT_MODEL else ""
        echo(f"{m.name}{mark}\n    {m.formula}\n    {m.description}")


@click.command("fit")
@click.argument("files", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option(
    "-o",
    "--output",
    required=True,
    type=click.Path(dir_okay=False),
    help="Map file to write (JSON).",
)
@click.option("--model", default=DEFAULT_MODEL, show_default=True, type=click.Choice(MODEL_NAMES))
@click.option(
    "--loss",
    default="l2",
    show_default=True,
    type=click.Choice(LOSSES),
    help="l2 least squares, l1 least absolute deviations (paper eq. 8, exact LP).",
)
@click.option(
    "--strategy",
    type=click.Choice(["LA", "SR", "MR"]),
    help="Override the strategy recorded in the map (default: from the data's rotors on the ESC).",
)
@selection_options
def fit_cmd(
    files: tuple[str, ...], output: str, model: str, loss: str, strategy: str | None, **kw: Any
) -> None:
    """Fit a thrust map Th = f(T, B) to stand logs and write it as JSON."""
    from thrustmap import api
    from thrustmap.core.files import atomic_write_text, check_output_path
    from thrustmap.fitting.loaders.checks import check_thrust_leaves_noise
    from thrustmap.fitting.selection.describe import describe as describe_selection

    # a Ds log's sidecar (run.meta.json) is an input too; run.json is a free name for the map
    sidecars = [s for f in files if (s := Path(f).with_suffix(".meta.json")).exists()]
    plan = check_output_path(output, inputs=[*files, *sidecars], what="map output")
    datasets = api.load_stand_logs(files, _column_map(kw))
    for ds in datasets:
        check_thrust_leaves_noise(ds)  # a map of pure noise is refused, not written
    out = api.fit(datasets, model=model, loss=loss, selection=_selection(kw), strategy=strategy)  # type: ignore[arg-type]
    atomic_write_text(output, out.map.dumps())
    s = out.map.metrics["in_sample"]
    for p in out.pool.points:
        r = p.report
        echo(
            f"{r['file']}: {plural(r['samples'], 'sample')} -> {plural(len(p), 'point')}"
            + (
                f" ({plural(r['plateaus'], 'plateau')}, "
                f"{plural(r.get('ramp_samples_kept', 0), 'quasi-static ramp sample')}, "
                f"{plural(r['settling_samples_dropped'], 'settling sample')} dropped)"
                if "plateaus" in r
                else ""
            )
        )
        if stair := describe_selection(r):
            echo(f"  {stair}")
        if "zero_subtracted_n" in r:
            echo(
                f"  thrust read from the load cell's zero: its rest plateau read "
                f"{r['zero_subtracted_n']:.4f} N, subtracted (a rotor at rest makes no thrust)"
            )
    echo(f"model {out.map.model} ({out.map.loss}): {out.map.model_def.formula}")
    if out.weighting:
        echo(out.weighting)
    echo(
        f"in-sample e_Th: mean {s['mean_pct']:.3f} % ± {s['std_pct']:.3f}, p95 {s['p95_pct']:.3f} %, "
        f"max {s['max_pct']:.3f} %, n={s['n']}"
    )
    echo(
        f"supported region (where the data are; outside it the map extrapolates): "
        f"{out.map.supported_region().describe()}"
    )
    volts = out.map.selection.get("measured_voltages_v") or []
    if volts:  # points within 5 % of each other are one voltage
        from thrustmap.fitting.voltages import describe_voltages

        click.echo(f"measured at {describe_voltages(volts)}")
    ident = out.map.identification
    if ident:
        echo(f"identification: {ident['reason']}")
        if ident.get("voltage_scaling"):
            echo(f"voltage scaling: {ident['voltage_scaling']}")
    echo(out.trust)
    echo(out.more_data)
    for w in out.warnings:
        echo(f"warning: {w}", err=True)
    echo(f"wrote {output}" + (" (replaced the previous file)" if plan.replaced else ""))


@click.command("compare")
@click.argument("files", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option(
    "--models",
    default=f"poly2,poly2-trunc,poly3,poly3-trunc,{DEFAULT_MODEL}",
    show_default=True,
    help="Comma-separated model names (see `thrustmap models`).",
)
@click.option(
    "--validate",
    "validation",
    default="in-sample",
    show_default=True,
    type=click.Choice(VALIDATIONS),
)
@click.option(
    "--folds",
    default=5,
    show_default=True,
    type=click.IntRange(min=2),
    help="Folds for --validate kfold.",
)
@click.option("--loss", default="l2", show_default=True, type=click.Choice(LOSSES))
@click.option("--json", "as_json", is_flag=True, help='Print {"rows": [...]}.')
@selection_options
def compare_cmd(
    files: tuple[str, ...],
    models: str,
    validation: str,
    folds: int,
    loss: str,
    as_json: bool,
    **kw: Any,
) -> None:
    """Compare models on stand logs under one validation mode."""
    from thrustmap import api

    names = [m.strip() for m in models.split(",") if m.strip()]
    if not names:
        raise ConfigError(
            f"--models {models!r} names no model; expected comma-separated names, e.g. "
            "motor,poly2 (`thrustmap models` lists them)"
        )
    datasets = api.load_stand_logs(files, _column_map(kw))
    rows = api.compare(
        datasets,
        names,
        validation,  # type: ignore[arg-type]  # click.Choice: one of the modes
        loss=loss,  # type: ignore[arg-type]  # click.Choice: l1 or l2
        selection=_selection(kw),
        folds=folds,
    )
    if as_json:
        click.echo(_json({"rows": [r.to_dict() for r in rows]}))
    else:
        echo(_rows_table(rows))


@click.command("evaluate")
@click.argument("map_file", type=click.Path(dir_okay=False))
@click.argument("files", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help='Print {"rows": [...]}.')
@selection_options
def evaluate_cmd(map_file: str, files: tuple[str, ...], as_json: bool, **kw: Any) -> None:
    """Score an existing map on stand logs: every point, and inside/outside its supported region beside it."""
    from thrustmap.fitting.fit.validation import evaluate
    from thrustmap.fitting.loaders.load import load_datasets
    from thrustmap.fitting.mapfile import ThrustMap

    tmap = ThrustMap.load(map_file)
    rows = evaluate(tmap, load_datasets(files, _column_map(kw)), _selection(kw))
    if as_json:
        click.echo(_json({"rows": [r.to_dict() for r in rows]}))
    else:
        echo(_rows_table(rows))


@click.command("predict")
@click.argument("map_file", type=click.Path(dir_okay=False))
@click.option("--thrust-n", type=float, help="Thrust per rotor, N (inverse map: gives throttle).")
@click.option(
    "--throttle",
    "throttle_native",
    type=float,
    help="Throttle in the map's native units (forward: gives thrust).",
)
@click.option("--throttle-pct", type=float, help="Throttle in % (forward: gives thrust).")
@click.option("--voltage-v", type=float, required=True, help="Battery voltage, V.")
@click.option("--no-correction", is_flag=True, help="Ignore the map's γ(B) flight correction.")
@click.option(
    "--extrapolate",
    is_flag=True,
    help="Answer beyond the evidence too (past the distance outside the map's data where the "
    "extrapolation benchmark shows its interval holds; without it: exit 1).",
)
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
def predict_cmd(
    map_file: str,
    thrust_n: float | None,
    throttle_native: float | None,
    throttle_pct: float | None,
    voltage_v: float,
    no_correction: bool,
    extrapolate: bool,
    as_json: bool,
) -> None:
    """Throttle for a thrust (the map), or thrust for a throttle (forward)."""
    from thrustmap.cli.predict import Query, run_predict

    given = [x is not None for x in (thrust_n, throttle_native, throttle_pct)]
    if sum(given) != 1:
        raise ConfigError("give exactly one of --thrust-n, --throttle, --throttle-pct")
    for opt, value in (("--throttle", throttle_native), ("--throttle-pct", throttle_pct)):
        if value is not None:
            physical.finite(value, opt)
    if thrust_n is not None:
        physical.rotor_thrust_n(thrust_n, "--thrust-n")
    physical.battery_voltage_v(voltage_v, "--voltage-v")
    if throttle_pct is not None and throttle_pct < 0:
        raise ConfigError(f"--throttle-pct: expected a value >= 0, got {throttle_pct:g}")
    query = Query(thrust_n, throttle_native, throttle_pct, voltage_v, not no_correction)
    code = run_predict(map_file, query, extrapolate=extrapolate, as_json=as_json)
    if code:
        sys.exit(code)  # exit 1: no answer (as spin and sweep exit 1 when a limit stops them)


@click.command("inspect")
@click.argument("files", nargs=-1, required=True, type=click.Path(dir_okay=False))
@selection_options
def inspect_cmd(files: tuple[str, ...], **kw: Any) -> None:
    """Show how stand logs load: format, scale, ranges, and what selection keeps."""
    import numpy as np

    from thrustmap.fitting.dataset import LAYOUTS
    from thrustmap.fitting.loaders.load import load_datasets
    from thrustmap.fitting.selection.describe import describe as describe_selection
    from thrustmap.fitting.selection.points import select

    sel = _selection(kw)
    for ds in load_datasets(files, _column_map(kw)):
        p = select(ds, sel)
        sc = ds.throttle_scale
        echo(
            f"{ds.path}\n  format {ds.format}, {len(ds)} samples, throttle scale "
            f"{sc.describe()}, rotors on ESC: {ds.rotors_on_esc or 'unknown'}"
        )
        echo(
            f"  throttle {np.min(ds.throttle_native):g}..{np.max(ds.throttle_native):g}"
            f"{'' if sc.unit_label == '1' else ' ' + sc.unit_label}, "
            f"thrust {np.min(ds.thrust_n):.3f}..{np.max(ds.thrust_n):.3f} N, "
            f"voltage {np.min(ds.voltage_v):.2f}..{np.max(ds.voltage_v):.2f} V"
        )
        for k, v in ds.meta.items():
            note = LAYOUTS.get(v, "") if k == "layout" else ""
            echo(f"  {k}: {_meta_value(k, v)}" + (f" ({note})" if note else ""))
        rules = ", ".join(
            f"{k}={v}" for k, v in p.report.items() if k != "file" and not isinstance(v, dict)
        )
        echo(f"  selection (what each rule did): {rules}")
        if stair := describe_selection(p.report):
            echo(f"  {stair}")
        if isinstance(top := p.report.get("past_top"), dict):
            from thrustmap.fitting.selection.top import TopCut

            echo(f"  top of the curve: {TopCut.describe(top)}")
