"""CLI: ``fleet extract`` and ``fleet gamma`` (thin over thrustmap.fleet; dask and pyarrow load
only inside the commands)."""

from __future__ import annotations

import contextlib
import logging
import sys
import time
from pathlib import Path
from typing import Any, TextIO

import click

from thrustmap.cli import textwidth
from thrustmap.cli.df_options import EXTRACT_FIELDS, df_click_options
from thrustmap.cli.textwidth import echo, plural
from thrustmap.core.errors import ConfigError
from thrustmap.rig.sigterm import terminate_as_exception

SHOW_REFUSED = 20  # refused logs listed by name; the rest are counted (all are in the table)


def _parse_size(text: str | None) -> int | None:
    if text is None or text.lower() == "auto":
        return None
    units = {"": 1, "b": 1, "kb": 1e3, "mb": 1e6, "gb": 1e9, "kib": 1024, "mib": 1024**2,
             "gib": 1024**3}  # fmt: skip
    t = text.strip().lower()
    num = t.rstrip("kmgib")
    try:
        value = float(num) * units[t[len(num) :]]
    except (ValueError, KeyError):
        raise ConfigError(
            f"--memory-per-worker '{text}': expected e.g. 2GiB, 1500MB or auto"
        ) from None
    if value < 256 * 1024**2:
        raise ConfigError(f"--memory-per-worker '{text}': at least 256 MiB per worker")
    return int(value)


def _require(*modules: str) -> None:
    """The fleet extra's libraries, or one line saying how to get them."""
    import importlib.util

    missing = [m for m in modules if importlib.util.find_spec(m) is None]
    if missing:
        raise ConfigError(
            f"thrustmap fleet needs {' and '.join(missing)}: pip install 'thrustmap[fleet]'"
        )


class _Bar:
    """Progress on stderr: on a terminal, one bar line redrawn in place and fitted to its width;
    elsewhere (a pipe, a file, CI) a plain ``progress:`` line every 10 %.

    Never a bar and another line on one line: every other line the command prints while the bar
    is shown goes through :meth:`note`, and log records through a filter on the log handlers
    (:meth:`attach`), which first clear the bar; the next update draws it again."""

    WIDTH = 30  # the bar's own characters, fewer on a narrow terminal

    def __init__(self, stream: TextIO | None = None, columns: int | None = None) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.tty = self.stream.isatty()
        self.columns = columns if columns is not None else (textwidth.width(err=True) or 80)
        self.started = time.monotonic()
        self.last_decile = -1
        self.refused = 0
        self.shown = float("-inf")
        self.drawn = False  # a bar is on the current line
        self._handlers: list[logging.Handler] = []

    def __call__(self, done: int, total: int, outcome: Any) -> None:
        self.refused += int(outcome.status == "refused")
        rate = done / max(time.monotonic() - self.started, 1e-9)
        frac = done / total if total else 1.0
        text = f"{done}/{plural(total, 'log')} ({rate:.1f}/s, {self.refused} refused)"
        now = time.monotonic()
        if self.tty:
            if now - self.shown >= 0.1 or done >= total or not self.drawn:
                self.shown = now
                self._draw(frac, text)
                if done >= total:
                    self._write("\n")
                    self.drawn = False
        elif int(frac * 10) > self.last_decile:
            self.last_decile = int(frac * 10)
            self._write(f"progress: {text}\n")

    def _draw(self, frac: float, text: str) -> None:
        room = self.columns - 1  # the last column of a line makes some terminals wrap
        width = min(self.WIDTH, room - len(text) - 3)
        if width >= 10:
            fill = int(frac * width)
            line = f"[{'#' * fill}{'.' * (width - fill)}] {text}"
        else:
            line = text[:room]
        self._write(f"\r\x1b[K{line}")
        self.drawn = True

    def clear(self) -> None:
        """Take the bar off the current line (the next update draws it again)."""
        if self.drawn:
            self._write("\r\x1b[K")
            self.drawn = False

    def note(self, text: str) -> None:
        """A line of its own while the bar may be shown."""
        self.clear()
        self._write(textwidth.wrap(text, self.columns if self.tty else None, err=True) + "\n")

    def end(self) -> None:
        self.clear()
        for h in self._handlers:
            h.removeFilter(self._before_record)
        self._handlers = []

    def attach(self) -> None:
        """Clear the bar before any log record reaches a handler of the root logger."""
        if self.tty:
            self._handlers = list(logging.getLogger().handlers)
            for h in self._handlers:
                h.addFilter(self._before_record)

    def _before_record(self, record: logging.LogRecord) -> bool:
        self.clear()
        return True

    def _write(self, text: str) -> None:
        with contextlib.suppress(OSError, ValueError):  # stderr closed: no progress, no crash
            self.stream.write(text)
            self.stream.flush()


@click.group("fleet")
def fleet_group() -> None:
    """Df and γ(B) over a fleet of flight logs, on local workers or Dask (pip install
    'thrustmap[fleet]')."""


@fleet_group.command("extract")
@click.argument("sources", nargs=-1, required=True)
@click.option("-o", "--output", "out_dir", required=True, type=click.Path(path_type=Path),
              help="Output folder: fleet.parquet and df/ (created when missing).")  # fmt: skip
@click.option("--masses", "masses_path", type=click.Path(path_type=Path),
              help="CSV of pattern,mass_kg: the first glob matching a log's name or path wins.")  # fmt: skip
@click.option("--map", "map_path", type=click.Path(path_type=Path), help="Stand map (per rotor).")
@df_click_options(EXTRACT_FIELDS)
@click.option("--format", "fmt", help="Reader name instead of content detection.")
@click.option("--workers", type=int,
              help="Local worker processes, forked from this command, one log at a time each; "
              "default: the machine's cores; 0: the plain serial loop in this command.")  # fmt: skip
@click.option("--scheduler",
              help="Address of an existing Dask scheduler (tcp://host:8786, or tls://host:8786 "
              "with Dask's own security configuration: docs/fleet.md).")  # fmt: skip
@click.option("--dashboard", "dashboard", is_flag=False, flag_value="127.0.0.1:8787",
              default=None, metavar="[ADDR]",
              help="Run the local workers as a Dask cluster and serve its dashboard at ADDR "
              "(default 127.0.0.1:8787; bokeh needed). Off unless given; every other server of "
              "the cluster is on 127.0.0.1.")  # fmt: skip
@click.option("--memory-per-worker", default="auto", show_default=True,
              help="Memory limit of each local worker (e.g. 2GiB); auto: min(4 GiB, RAM/workers).")  # fmt: skip
@click.option("--max-log-mb", type=float, default=512.0, show_default=True,
              help="Logs larger than this are refused unread (bounds a worker's memory).")  # fmt: skip
@click.option("--force", is_flag=True,
              help="Extract a flight whose battery is another cell count than the map's pack, "
              "or whose mass the map cannot hover, anyway (as `flightlog extract --force`: "
              "recorded in its Df sidecar).")  # fmt: skip
@click.option("--quiet", is_flag=True, help="No progress bar.")
def extract_cmd(
    sources: tuple[str, ...],
    out_dir: Path,
    masses_path: Path | None,
    map_path: Path | None,
    fmt: str | None,
    workers: int | None,
    scheduler: str | None,
    dashboard: str | None,
    memory_per_worker: str,
    max_log_mb: float,
    force: bool,
    quiet: bool,
    **df_values: Any,
) -> None:
    """Extract Df from every log in SOURCES (folders, globs, files) into OUT_DIR.

    Each log goes through the rules of `flightlog extract`; one Df per log (OUT_DIR/df/) and one
    table of outcomes (OUT_DIR/fleet.parquet). A bad log is listed with its reason and never
    stops the fleet. A re-run skips logs already done with the same content and options.
    """
    from thrustmap.fleet import run

    dask_local, dash = _check_modes(workers, scheduler, dashboard, max_log_mb)
    mem = _parse_size(memory_per_worker)
    config = _fleet_config(out_dir, masses_path, map_path, fmt, max_log_mb, df_values)
    config.force = force
    # the number of local workers and their memory, checked before anything is read
    spec = None if workers == 0 or scheduler is not None else run.local_cluster_spec(
        workers, mem, dash)  # fmt: skip
    limits = f"logs over {max_log_mb:g} MB refused unread"
    fleet = _FleetRun(workers, scheduler, dask_local, dash, spec, None if quiet else _Bar(), limits)
    started = time.monotonic()
    result = fleet.extract(sources, config)
    _print_outcome(result, time.monotonic() - started)


def _check_modes(
    workers: int | None, scheduler: str | None, dashboard: str | None, max_log_mb: float
) -> tuple[bool, str | None]:
    """Where the logs run, checked: (whether on a local Dask cluster, its dashboard address)."""
    from thrustmap.fleet import local, run

    if workers is not None and scheduler is not None:
        raise ConfigError("give --workers (local workers) or --scheduler, not both")
    if dashboard is not None and (scheduler is not None or workers == 0):
        raise ConfigError(
            "--dashboard is for a local Dask cluster (not with --scheduler or --workers 0)"
        )
    # local workers are processes forked from this command (thrustmap.fleet.local); Dask runs
    # them only to serve its dashboard, or where fork is not safe (not Linux)
    dask_local = workers != 0 and scheduler is None and (dashboard is not None
                                                         or not local.available())  # fmt: skip
    _require("pyarrow", *(("distributed",) if scheduler is not None or dask_local else ()))
    dash = None if dashboard is None else run.dashboard_address(dashboard)
    if max_log_mb <= 0:
        raise ConfigError(f"--max-log-mb must be positive, got {max_log_mb:g}")
    return dask_local, dash


def _fleet_config(
    out_dir: Path,
    masses_path: Path | None,
    map_path: Path | None,
    fmt: str | None,
    max_log_mb: float,
    df_values: dict[str, Any],
) -> Any:
    """The fleet run's ``FleetConfig``: its paths checked, the masses read."""
    from thrustmap.fleet import run

    if map_path is not None and not map_path.is_file():
        raise ConfigError("map file not found", file=str(map_path))
    if out_dir.exists() and not out_dir.is_dir():
        raise ConfigError("the output must be a folder", file=str(out_dir))
    return run.FleetConfig(
        out_dir=out_dir.absolute(),
        df_options=df_values,
        masses=run.read_masses(masses_path) if masses_path else [],
        map_path=map_path,
        fmt=fmt,
        max_log_bytes=int(max_log_mb * 2**20),
    )


class _FleetRun:
    """One ``fleet extract`` run on its workers (serial, forked, a local Dask cluster or a
    scheduler): started, said on stderr, and on every way out stopped, no child left behind."""

    def __init__(
        self,
        workers: int | None,
        scheduler: str | None,
        dask_local: bool,
        dash: str | None,
        spec: Any,
        bar: _Bar | None,
        limits: str,
    ) -> None:
        from thrustmap.fleet import run

        self.workers, self.scheduler, self.dask_local = workers, scheduler, dask_local
        self.dash, self.spec, self.bar, self.limits = dash, spec, bar, limits
        self.holder: dict[str, Any] = {}
        # what a Dask cluster may leave behind is looked for at the end (forked workers are
        # each stopped and confirmed gone by the pool itself)
        self.before = run.child_pids() if scheduler is not None or dask_local else set()

    def say(self, text: str) -> None:
        """A line on stderr of its own (the bar, if shown, is cleared first)."""
        if self.bar is not None:
            self.bar.note(text)
        else:
            echo(text, err=True)

    def begin(self) -> Any:
        """Start the local Dask cluster in the background (once)."""
        from thrustmap.fleet import run

        holder, spec = self.holder, self.spec
        if "start" not in holder:
            assert spec is not None
            self.say(
                f"local Dask cluster: {spec.workers} worker processes, one log at a time each, "
                f"memory limit {spec.memory_limit_bytes / 2**30:.2f} GiB per worker; "
                f"{self.limits}"
            )
            holder["local"] = True  # from here, whatever happens, no child may outlive it
            holder["spec"] = spec
            # a background thread: a Ctrl-C during the start-up stops the run at once
            holder["start"] = run.LocalClusterStart(spec)
        return holder["start"]

    def connect(self) -> tuple[Any, int]:
        from thrustmap.fleet import run

        if self.scheduler is not None:
            client = self.holder["client"] = run.connect(self.scheduler)
            threads = sum(client.nthreads().values()) or 1
            self.say(f"Dask scheduler {self.scheduler}: {threads} worker threads")
            return client, 2 * threads
        _, client = self.begin().wait()
        if self.dash is not None:
            self.say(f"Dask dashboard: {client.dashboard_link}")
        return client, 2 * self.holder["spec"].workers

    def on_local_workers(self, tasks: list[Any]) -> Any:
        from thrustmap.fleet import local

        spec = self.spec
        assert spec is not None
        n = min(spec.workers, len(tasks))  # no idle worker for a handful of logs
        self.say(
            f"local workers: {plural(n, 'process', 'processes')} forked from this command, one "
            f"log at a time each, memory limit {spec.memory_limit_bytes / 2**30:.2f} GiB per "
            f"worker; {self.limits}"
        )
        pool = self.holder["pool"] = local.ForkPool(local.LocalSpec(n, spec.memory_limit_bytes))
        return pool.run(tasks)

    def extract(self, sources: tuple[str, ...], config: Any) -> Any:
        """Run the fleet; the workers are stopped on every way out."""
        from thrustmap.fleet import run

        workers, scheduler, dask_local = self.workers, self.scheduler, self.dask_local
        if workers == 0:
            self.say("serial loop in this process (no worker processes)")
        if self.bar is not None:
            self.bar.attach()
        try:
            try:
                # SIGTERM (a batch system, systemd, kill) or SIGHUP ends the run as Ctrl-C does:
                # the table of what finished is written, the workers stopped, the run resumable
                with terminate_as_exception(stopping="the fleet run", sigint_always=False):
                    return run.fleet_extract(
                        sources,
                        config,
                        connect=self.connect if scheduler is not None or dask_local else None,
                        local=None
                        if workers == 0 or scheduler or dask_local
                        else self.on_local_workers,
                        progress=self.bar,
                    )
            except KeyboardInterrupt:
                self.say(
                    f"interrupted: the table of the logs finished so far is in "
                    f"{config.out_dir / 'fleet.parquet'}; run the same command again to resume"
                )
                raise
        finally:
            self.close()

    def close(self) -> None:
        """The bar taken down, the workers stopped (closing never hides the real outcome, and
        ``stop_children`` is the backstop)."""
        from thrustmap.fleet import run

        holder = self.holder
        if self.bar is not None:
            self.bar.end()
        if "pool" in holder:
            holder["pool"].close()
        if "start" in holder:
            holder["start"].close()
        elif holder.get("client") is not None:
            with contextlib.suppress(Exception):
                holder["client"].close(timeout=10)
        if holder.get("local"):
            run.stop_children(self.before)


def _print_outcome(result: Any, elapsed: float) -> None:
    """The counts by status, the refused logs (the first SHOW_REFUSED by name), the table."""
    counts: dict[str, int] = {}
    for o in result.outcomes:
        counts[o.status] = counts.get(o.status, 0) + 1
    echo(
        f"{plural(result.total, 'log')}: {counts.get('ok', 0)} extracted, {counts.get('empty', 0)} with no "
        f"steady flight, {counts.get('refused', 0)} refused; {result.reused} already done "
        f"(skipped); {elapsed:.1f} s"
    )
    refused = sorted((o for o in result.outcomes if o.status == "refused"), key=lambda o: o.path)
    for o in refused[:SHOW_REFUSED]:
        echo(f"  refused: {o.reason}")
    if len(refused) > SHOW_REFUSED:
        echo(f"  ... and {len(refused) - SHOW_REFUSED} more refused (see the table)")
    echo(f"wrote {result.table_path}")


@fleet_group.command("gamma")
@click.argument("out_dir", type=click.Path(path_type=Path))
@click.option("--map", "map_path", type=click.Path(path_type=Path),
              help="Stand map: each fitted group also gets OUT_DIR/gamma/KEY.map.json, the "
              "map with that group's γ block (as `gamma fit -o`).")  # fmt: skip
@click.option("--loss", type=click.Choice(["l1", "l2"]), default="l1", show_default=True)
@click.option("--min-logs", type=int, default=3, show_default=True,
              help="Groups with fewer logs are reported, not fitted.")  # fmt: skip
@click.option("--min-samples", type=int, default=100, show_default=True,
              help="Groups with fewer Df samples are reported, not fitted.")  # fmt: skip
@click.option("--min-span-v", type=float, default=0.5, show_default=True,
              help="Groups whose flown voltage spans less are reported, not fitted.")  # fmt: skip
@click.option("-o", "--report", "report_path", type=click.Path(path_type=Path),
              help="Fleet HTML report (default: OUT_DIR/fleet-report.html).")  # fmt: skip
@click.option("--json", "as_json", is_flag=True, help="Print the groups as JSON.")
def gamma_cmd(
    out_dir: Path,
    map_path: Path | None,
    loss: str,
    min_logs: int,
    min_samples: int,
    min_span_v: float,
    report_path: Path | None,
    as_json: bool,
) -> None:
    """Group the logs of OUT_DIR by airframe and fit γ(B) per group (the rule of `gamma fit`).

    Writes OUT_DIR/fleet-gamma.json, the HTML report and, with --map, one corrected map per
    fitted group. Groups too small or too narrow in voltage are reported, not fitted.
    """
    import json

    _require("pyarrow")
    from thrustmap.core.files import atomic_write_text, check_output_path
    from thrustmap.fitting.mapfile import ThrustMap, file_sha256
    from thrustmap.fleet.groups import fleet_gamma
    from thrustmap.fleet.report import gamma_formula, write_fleet_report
    from thrustmap.fleet.table import TABLE_NAME, read_table

    if min_logs < 1 or min_samples < 10 or min_span_v < 0:
        raise ConfigError("--min-logs ≥ 1, --min-samples ≥ 10 and --min-span-v ≥ 0 expected")
    outcomes = read_table(out_dir / TABLE_NAME)
    report = report_path or out_dir / "fleet-report.html"
    check_output_path(report, inputs=[*([map_path] if map_path else [])], what="fleet report")
    tmap = ThrustMap.load(map_path) if map_path else None
    groups = fleet_gamma(
        outcomes,
        out_dir,
        tmap,
        loss=loss,
        min_logs=min_logs,
        min_samples=min_samples,
        min_span_v=min_span_v,
    )
    if tmap is not None:
        from thrustmap.fitting.gamma import corrected_map

        if any(g.fit is not None for g in groups):
            (out_dir / "gamma").mkdir(exist_ok=True)
        for g in groups:
            if g.fit is not None:
                sources = [{"path": str(p), "sha256": file_sha256(p)} for p in g.df_paths]
                out_map = corrected_map(tmap, g.fit, sources)
                atomic_write_text(out_dir / "gamma" / f"{g.key}.map.json", out_map.dumps())
    summary = [g.to_dict() for g in groups]
    atomic_write_text(
        out_dir / "fleet-gamma.json", json.dumps(summary, indent=2, default=float) + "\n"
    )
    write_fleet_report(outcomes, groups, report)
    if as_json:
        click.echo(json.dumps(summary, indent=2, default=float))
        if not any(g.fit is not None for g in groups):
            raise SystemExit(1)  # as without --json: no group fitted
        return
    for g in groups:
        head = f"{g.label}: {plural(len(g.logs), 'log')}, {plural(g.samples, 'sample')}"
        if g.voltage_v is not None:
            head += f", {g.voltage_v[0]:.2f}..{g.voltage_v[1]:.2f} V"
        if g.fit is None:
            echo(f"{head}: {g.status}: {g.reason}")
            continue
        band = (
            "" if g.band is None else f", 95 % of samples within {g.band[0]:+.4f}/{g.band[1]:+.4f}"
        )
        echo(
            f"{head}: γ(B) = {gamma_formula(g.fit.correction.coefficients)} (degree "
            f"{g.fit.degree}{band})"
        )
    refused = sum(o.status == "refused" for o in outcomes)
    fitted = sum(g.fit is not None for g in groups)
    echo(
        f"{fitted} of {len(groups)} groups fitted; "
        f"{plural(refused, 'log')} refused (by reason in the report); wrote {report} and "
        f"{out_dir / 'fleet-gamma.json'}"
        + (
            f" and {fitted} corrected map(s) in {out_dir / 'gamma'}"
            if tmap is not None and fitted
            else ""
        )
    )
    if not fitted:
        # nothing to apply: said, and the exit code says it too (a script must not go on to
        # use corrected maps that were never written)
        click.echo(
            "no group fitted, so no γ(B)"
            + (" and no corrected map" if tmap is not None else "")
            + ": "
            + (
                "; ".join(f"{g.label}: {g.status}: {g.reason}" for g in groups)
                or "no log gave a Df"
            ),
            err=True,
        )
        raise SystemExit(1)
