"""The ``thrustmap`` command: a thin layer over the library.

Subcommands live in sibling modules and are imported only when used, so a missing optional
dependency of one command never breaks the others. Every ``ThrustmapError`` becomes one line
on stderr and exit code 2; no traceback reaches the user unless ``--debug`` is given.
"""

from __future__ import annotations

import importlib
import logging
import os
import sys
import warnings
from typing import Any, TextIO

import click

from thrustmap.cli import textwidth
from thrustmap.core.errors import ThrustmapError

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
    "fleet": "fleet:fleet_group",
    "export": "exportcmd:export_cmd",
    "report": "report:report_cmd",
    "plot": "report:plot_cmd",
    "sim-serve": "simserve:simserve_cmd",
    "stand": "standcmd:stand_group",
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
    "fleet": "Df and gamma(B) over a fleet of flight logs, on Dask.",
    "export": "Export a map for a throttle encoding or a firmware.",
    "report": "A self-contained HTML report of a map and its data.",
    "plot": "Publication figures of a map: surface, slices, residuals, coverage, gamma...",
    "sim-serve": "Serve a simulated device (a Flight Stand core) for scripts and drivers.",
    "stand": "DIY line stands: calibrate the load cell, run the firmware's own sweep.",
}


class LazyGroup(click.Group):
    """The top-level group: commands imported when used, help wrapped between words.

    Bare ``thrustmap`` prints its help (exit 0); a group given no subcommand
    (``thrustmap flightlog``) prints a short usage on stderr (exit 2).
    """

    context_class = textwidth.Context

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        if not args and not ctx.resilient_parsing:
            click.echo(ctx.get_help())
            ctx.exit(0)
        return super().parse_args(ctx, args)

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except click.exceptions.NoArgsIsHelpError as exc:
            click.echo(textwidth.short_usage(exc.ctx), err=True)
            # SystemExit, not click's Exit: cli.main(standalone_mode=False) returns Exit's code
            # as the command's result, which main() does not read
            raise SystemExit(2) from None
        except click.MissingParameter as exc:
            # click lists choices on tab-indented lines; one line of plain words instead
            message = " ".join(exc.format_message().split())
            raise click.UsageError(message, ctx=exc.ctx) from None

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

        # every --help says where the pictures are, wrapped between words
        return textwidth.use_formatter(attach(command, cmd_name))


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="thrustmap", prog_name="thrustmap")
@click.option("-v", "--verbose", count=True, help="More log output (-vv for debug).")
@click.option("--debug", is_flag=True, help="Show tracebacks for internal errors.")
@click.pass_context
def cli(ctx: click.Context, verbose: int, debug: bool) -> None:
    """Calibrate multirotor thrust maps on a thrust stand and correct them from flight logs."""
    level = logging.WARNING - 10 * min(verbose, 2)
    logging.getLogger().setLevel(level)
    handler = _CliLogHandler.current
    if handler is not None:
        handler.verbose = verbose
    else:  # cli() called directly (tests, embedding): plain stderr logging
        logging.basicConfig(level=level, stream=sys.stderr)
        for root_handler in logging.getLogger().handlers:
            root_handler.setFormatter(CliFormatter())
    ctx.ensure_object(dict)
    ctx.obj["debug"] = debug


class CliFormatter(logging.Formatter):
    """A log record as the CLI's own lines read: ``warning: ...``, ``error: ...``.

    The logger's name is an implementation detail, shown only at debug level (``-vv``), where
    it helps; a CRITICAL line keeps its upper-case word, because it means a motor we commanded
    may still be turning.
    """

    PREFIX = {
        logging.DEBUG: "debug: ",
        logging.INFO: "",
        logging.WARNING: "warning: ",
        logging.ERROR: "error: ",
        logging.CRITICAL: "CRITICAL: ",
    }

    def format(self, record: logging.LogRecord) -> str:
        message = " ".join(record.getMessage().splitlines())
        if record.exc_info and record.levelno <= logging.DEBUG:
            message += " " + " ".join(self.formatException(record.exc_info).splitlines())
        prefix = self.PREFIX.get(record.levelno, f"{record.levelname.lower()}: ")
        if record.levelno <= logging.DEBUG:
            return f"{prefix}{record.name}: {message}"
        return prefix + message


#: commands that drive hardware or run for minutes: their warnings are shown as they happen
LIVE_COMMANDS = frozenset({"sweep", "spin", "probe", "demo", "ports", "live"})


_MAX_REMEMBERED = 1000  # distinct lines remembered to show each warning once


class _CliLogHandler(logging.Handler):
    """stderr logging for one command run.

    Warnings of a file command are held until it ends: shown when it succeeds, replaced by the
    count when it fails (so a refused input gives exactly one line; ``-v`` shows them all).
    Commands in LIVE_COMMANDS (hardware) show every record at once.
    """

    current: _CliLogHandler | None = None

    def __init__(self, stream: TextIO, *, live: bool) -> None:
        super().__init__(logging.DEBUG)
        self.stream = stream
        self.live = live
        self.verbose = 0
        self.held: list[str] = []
        self.shown: set[str] = set()
        self.setFormatter(CliFormatter())

    def emit(self, record: logging.LogRecord) -> None:
        try:
            line = " ".join(self.format(record).splitlines())
        except Exception:  # pragma: no cover - a broken record must not take the command down
            self.handleError(record)
            return
        if record.levelno <= logging.WARNING:
            if line in self.shown or line in self.held:
                return  # the same warning twice says nothing new (errors are always shown)
            if len(self.shown) >= _MAX_REMEMBERED:
                self.shown.clear()  # bounded: a long run forgets, at worst repeating a line
        if self.live or self.verbose:
            self.shown.add(line)
            self._write(line)
        else:
            self.held.append(line)

    def _write(self, line: str) -> None:
        if not line.startswith(("error: ", "CRITICAL: ")):  # an error stays one line
            line = textwidth.wrap(line, err=True)  # a note fits the terminal, between words
        try:
            self.stream.write(line + "\n")
            self.stream.flush()
        except (OSError, ValueError):  # pragma: no cover - stderr closed
            pass

    def flush_held(self) -> None:
        for line in self.held:
            self.shown.add(line)
            self._write(line)
        self.held.clear()

    def summary(self) -> str:
        n = len(self.held)
        self.held.clear()
        return f" ({n} warning{'s' if n != 1 else ''} before it; -v shows them)" if n else ""


def _show_warning(
    message: Warning | str,
    category: type[Warning],
    filename: str,
    lineno: int,
    file: TextIO | None = None,
    line: str | None = None,
) -> None:
    """Python warnings (numpy, pandas) go through logging, on one line, never raw to stderr."""
    level = logging.DEBUG if issubclass(category, RuntimeWarning) else logging.WARNING
    logging.getLogger("thrustmap.warnings").log(
        level, "%s: %s", category.__name__, " ".join(str(message).splitlines())
    )


def _command_name(args: list[str]) -> str | None:
    return next((a for a in args if not a.startswith("-")), None)


#: the thread-pool sizes of the BLAS and OpenMP libraries numpy (and scipy) may load
BLAS_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def limit_blas_threads(environ: dict[str, str] | os._Environ[str] = os.environ) -> bool:
    """One BLAS/OpenMP thread, unless the user set any of :data:`BLAS_THREAD_VARS`.

    No command runs a matrix product large enough to gain from threads, while OpenBLAS starts
    one spinning thread per core when numpy is imported: 0.08-0.1 s of CPU on every run of a
    short command (``flightlog extract`` of a 0.5 MB log takes ~0.15 s in all). Only effective
    before numpy is first imported; inherited by the processes a command starts (fleet
    workers set the same). Returns whether it set them."""
    if any(environ.get(v) for v in BLAS_THREAD_VARS):
        return False
    for v in BLAS_THREAD_VARS:
        environ[v] = "1"
    return True


def main(argv: list[str] | None = None) -> Any:
    """Console entry point: maps errors to one-line messages and exit codes.

    stdout carries only the command's output; logging and Python warnings go to stderr through
    one handler (see :class:`_CliLogHandler`); a ``ThrustmapError`` is one line and exit 2.
    """
    limit_blas_threads()
    args = list(argv if argv is not None else sys.argv[1:])
    handler = _CliLogHandler(sys.stderr, live=_command_name(args) in LIVE_COMMANDS)
    root = logging.getLogger()
    root.addHandler(handler)
    previous, _CliLogHandler.current = _CliLogHandler.current, handler
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("default")
            warnings.showwarning = _show_warning
            code = _run(args, handler)
    finally:
        root.removeHandler(handler)
        _CliLogHandler.current = previous
    if code:
        sys.exit(code)
    return None


def _run(args: list[str], handler: _CliLogHandler) -> int:
    code = _run_inner(args, handler)
    if code == 0:
        handler.flush_held()
    return code


def _run_inner(args: list[str], handler: _CliLogHandler) -> int:
    debug = "--debug" in args
    try:
        cli.main(args=args, prog_name="thrustmap", standalone_mode=False)
        return 0
    except click.exceptions.Abort as exc:  # click turns Ctrl-C (and EOF at a prompt) into this
        handler.flush_held()
        cause = exc.__cause__
        why = " ".join(str(cause).splitlines()) if isinstance(cause, KeyboardInterrupt) else ""
        word = "interrupted" if isinstance(cause, KeyboardInterrupt) else "aborted"
        click.echo(word + (f": {why}" if why else ""), err=True)
        return 130
    except click.ClickException as exc:
        message = " ".join(exc.format_message().splitlines())
        click.echo(f"error: {message}{handler.summary()}", err=True)
        return exc.exit_code
    except click.exceptions.Exit as exc:
        handler.flush_held()
        return exc.exit_code
    except ThrustmapError as exc:
        click.echo(f"error: {' '.join(str(exc).splitlines())}{handler.summary()}", err=True)
        return 2
    except KeyboardInterrupt as exc:  # Ctrl-C (SIGTERM where a command turns it into one)
        handler.flush_held()
        why = " ".join(str(exc).splitlines())
        click.echo("interrupted" + (f": {why}" if why else ""), err=True)
        return 130
    except Exception as exc:  # a bug: say so in one line, traceback only on request
        handler.flush_held()
        if debug:
            raise
        click.echo(
            f"internal error: {type(exc).__name__}: {exc} (run with --debug for a traceback)",
            err=True,
        )
        return 1
