"""CLI: ``report`` (a self-contained HTML report of a map) and ``plot`` (one figure for papers).

matplotlib and the report package are imported inside the commands, so the CLI starts fast.
"""

from __future__ import annotations

import time
from pathlib import Path

import click

from thrustmap.cli.textwidth import echo
from thrustmap.core.errors import ConfigError

FIGURE_NAMES = (
    "surface",
    "slices",
    "residuals",
    "coverage",
    "sweep",
    "gamma",
    "errors-by-voltage",
)
PLOT_FORMATS = ("png", "svg", "pdf")


@click.command("report")
@click.argument("map_file", metavar="MAP", type=click.Path(dir_okay=False))
@click.argument("data", nargs=-1, type=click.Path(dir_okay=False))
@click.option(
    "-o",
    "--output",
    default="report.html",
    show_default=True,
    type=click.Path(dir_okay=False),
    help="HTML file to write (self-contained: opens offline).",
)
def report_cmd(map_file: str, data: tuple[str, ...], output: str) -> None:
    """Write a self-contained HTML report of MAP: provenance, raw sweeps and what selection kept,
    the surface with its data, residuals, every model's validation, coverage and uncertainty,
    γ(B) and its flight errors, and firmware exports.

    DATA are the stand logs the map was fitted from; omitted, they are found from the paths the
    map recorded (next to the map when moved with it)."""
    from thrustmap.core.files import check_output_path
    from thrustmap.report.data import build
    from thrustmap.report.html import write_report

    start = time.perf_counter()
    check_output_path(output, inputs=[map_file, *data], what="report")
    rd = build(map_file, list(data) or None)
    size = write_report(rd, output)
    for note in rd.notes:
        echo(f"note: {note}", err=True)
    echo(
        f"wrote {output} ({size / 1e6:.1f} MB, {time.perf_counter() - start:.1f} s): "
        f"open it in any browser, no network needed"
    )


@click.command("plot")
@click.argument("figure", type=click.Choice(FIGURE_NAMES))
@click.argument("map_file", metavar="MAP", type=click.Path(dir_okay=False))
@click.argument("data", nargs=-1, type=click.Path(dir_okay=False))
@click.option(
    "-o",
    "--output",
    required=True,
    type=click.Path(dir_okay=False),
    help="Figure file: .png, .svg or .pdf (from the extension).",
)
@click.option("--dpi", default=200, show_default=True, help="Resolution of PNG output.")
def plot_cmd(figure: str, map_file: str, data: tuple[str, ...], output: str, dpi: int) -> None:
    """Draw one of the report's figures of MAP for a paper (matplotlib).

    surface: Th(T, B) with the data (paper Fig. 6); slices: throttle vs thrust at several
    voltages; residuals: against thrust and voltage; coverage: data and prediction interval;
    sweep: raw sweeps with what selection kept (Fig. 5); gamma: γ(B) with its data (Fig. 7);
    errors-by-voltage: e_Th and e_T before/after γ (Figs. 8-9)."""
    from thrustmap.core.files import atomic_write_bytes, check_output_path
    from thrustmap.report.data import build
    from thrustmap.report.figures import render

    fmt = Path(output).suffix.lower().lstrip(".")
    if fmt not in PLOT_FORMATS:
        raise ConfigError(
            f"-o {output}: expected a .png, .svg or .pdf file name, got '.{fmt or '?'}'"
        )
    if not 30 <= dpi <= 1200:
        raise ConfigError(f"--dpi: expected 30..1200, got {dpi}")
    check_output_path(output, inputs=[map_file, *data], what="figure")
    rd = build(map_file, list(data) or None, with_exports=False, with_validation=False)
    if figure in ("gamma", "errors-by-voltage") and rd.gamma is None:
        raise ConfigError(
            f"{map_file}: the map has no γ(B) correction; fit one with `thrustmap gamma fit`"
        )
    atomic_write_bytes(output, render(figure, rd, fmt, dpi=dpi))
    echo(f"wrote {output}")
