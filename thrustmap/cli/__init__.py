"""The ``thrustmap`` command: a thin layer over the library.

Subcommands live in sibling modules and are imported only when used, so a missing optional
dependency of one command never breaks the others. Every ``ThrustmapError`` becomes one line
on stderr and exit code 2; no traceback reaches the user unless ``--debug`` is given.
"""

from __future__ import annotations

import importlib
import logging
import sys
from typing import Any

import click

from thrustmap.errors import ThrustmapError

log = logging.getLogger("thrustmap")

#: command name -> "module:attribute" (relative to thrustmap.cli), loaded lazily.
COMMANDS: dict[str, str] = {
    "models": "fitcmd:models_cmd",
    "fit": "fitcmd:fit_cmd",
    "compare": "fitcmd:compare_cmd",
    "evaluate": "fitcmd:evaluate_cmd",
    "predict": "fitcmd:predict_cmd",
    "inspect": "fitcmd:inspect_cmd",
    "ports": "hardware:ports_cmd",
    "probe": "hardware:probe_cmd",
    "spin": "hardware:spin_cmd",
    "sweep": "bench:sweep_cmd",
    "demo": "bench:demo_cmd",
    "flightlog": "flight:flightlog_group",
    "gamma": "flight:gamma_group",
    "export": "exportcmd:export_cmd",
    "report": "report:report_cmd",
    "plot": "report:plot_cmd",
}


#: command name -> its one-line summary, so `thrustmap --help` lists the commands without
#: importing them (a command missing here is imported to read its summary).
SUMMARIES: dict[str, str] = {
    "models": "List the thrust-map models with their formulas.",
    "fit": "Fit a thrust map to stand logs.",
    "compare": "Compare models on stand logs under a validation mode.",
    "evaluate": "Score a map on new stand data.",
    "predict": "Throttle for a thrust (or thrust for a throttle) at a voltage.",
    "inspect": "Show how stand logs load and what selection keeps.",
    "ports": "List serial ports with a guess at what each is.",
    "probe": "Identity and a live reading of a flight controller or a stand.",
    "spin": "One short, capped, confirmed motor spin.",
    "sweep": "Run a bench sweep with interlocks and record it as a Ds log.",
    "demo": "The paper's SR and MR campaigns on the simulator, fitted and compared.",
    "flightlog": "Flight logs: inspect them and extract Df.",
    "gamma": "Fit the flight correction factor gamma(B).",
    "export": "Export a map for a throttle encoding or a firmware.",
    "report": "A self-contained HTML report of a map and its data.",
    "plot": "Publication figures of a map: surface, slices, residuals, coverage, gamma...",
}


class LazyGroup(click.Group):
    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(COMMANDS)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        rows = []
        for name in self.list_commands(ctx):
            summary = SUMMARIES.get(name)
            if summary is None:
                command = self.get_command(ctx, name)
                if command is None or command.hidden:
                    continue
                summary = command.get_short_help_str(formatter.width)
            rows.append((name, summary))
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        target = COMMANDS.get(cmd_name)
        if target is None:
            return None
        module_name, attr = target.split(":")
        try:
            module = importlib.import_module(f"thrustmap.cli.{module_name}")
        except ModuleNotFoundError as exc:
            if exc.name and exc.name.startswith("thrustmap.cli."):
                return None  # command not built yet
            raise
        command = getattr(module, attr, None)
        if not isinstance(command, click.Command):
            return None
        from thrustmap.cli.pictures import attach

        return attach(command, cmd_name)  # every --help says where the pictures are


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="thrustmap", prog_name="thrustmap")
@click.option("-v", "--verbose", count=True, help="More log output (-vv for debug).")
@click.option("--debug", is_flag=True, help="Show tracebacks for internal errors.")
@click.pass_context
def cli(ctx: click.Context, verbose: int, debug: bool) -> None:
    """Calibrate multirotor thrust maps on a thrust stand and correct them from flight logs."""
    level = logging.WARNING - 10 * min(verbose, 2)
    logging.basicConfig(
        level=level, format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr
    )
    ctx.ensure_object(dict)
    ctx.obj["debug"] = debug


def main(argv: list[str] | None = None) -> Any:
    """Console entry point: maps errors to one-line messages and exit codes."""
    debug = "--debug" in (argv if argv is not None else sys.argv[1:])
    try:
        return cli.main(args=argv, prog_name="thrustmap", standalone_mode=False)
    except click.exceptions.Abort:
        click.echo("aborted", err=True)
        sys.exit(130)
    except click.ClickException as exc:
        exc.show()
        sys.exit(exc.exit_code)
    except click.exceptions.Exit as exc:
        sys.exit(exc.exit_code)
    except ThrustmapError as exc:
        click.echo(f"error: {exc}", err=True)
        sys.exit(2)
    except KeyboardInterrupt:
        click.echo("interrupted", err=True)
        sys.exit(130)
    except Exception as exc:  # a bug: say so in one line, traceback only on request
        if debug:
            raise
        click.echo(
            f"internal error: {type(exc).__name__}: {exc} (run with --debug for a traceback)",
            err=True,
        )
        sys.exit(1)
