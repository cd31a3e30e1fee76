"""The no-hardware demo: the seed paper's bench campaign on the built-in simulator.

For each strategy — SR (one rotor on the ESC) and MR (four) — a simulated Betaflight FC
(MSP, PWM 1000–2000 µs, as in the paper) drives an xNova 2207 on 6S while a simulated Tyto
1585 stand measures it, through the real drivers and runner. The paper's four experiments
(steps, stairs up, stairs down, ramp) are recorded as Ds logs, then every model is scored
in-sample (the paper's Table 3), held out by file, and against the simulator's true map.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from pathlib import Path

import numpy as np

from thrustmap.core.clock import SimClock
from thrustmap.core.errors import ConfigError
from thrustmap.core.files import atomic_write_text
from thrustmap.fitting.fit.fitmap import fit_map
from thrustmap.fitting.fit.validation import compare
from thrustmap.fitting.loaders.load import load_datasets
from thrustmap.fitting.mapfile import ThrustMap
from thrustmap.fitting.selection.options import Selection
from thrustmap.protocols.transport import open_transport
from thrustmap.rig import plans
from thrustmap.rig.fc.msp import MspThrottleOutput
from thrustmap.rig.interlocks import Limits
from thrustmap.rig.run_types import RunConfig, RunResult
from thrustmap.rig.runner import record_sweep
from thrustmap.rig.sim import peers
from thrustmap.rig.sim.physics import PhysicsPlant
from thrustmap.rig.sim.stand_peers import SIM_TYTO_CALIBRATION
from thrustmap.rig.stand.tyto import TytoStand

log = logging.getLogger(__name__)

MODELS = ("poly2", "poly2-trunc", "poly3", "poly3-trunc", "motor")
STRATEGIES = {"SR": 1, "MR": 4}
#: the demo's list of the recordings it wrote (path relative to the output folder -> sha256), one
#: in each strategy's folder
MANIFEST = "thrustmap-demo.json"


def recording_paths(out_dir: Path) -> list[Path]:
    """Every Ds log (and sidecar) the demo writes into ``out_dir``."""
    paths = []
    for strategy in STRATEGIES:
        for name in experiments():
            csv = out_dir / strategy.lower() / f"xnova-{strategy}-{name}.csv"
            paths += [csv, csv.with_suffix(".meta.json")]
    return paths


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _manifest_files(path: Path) -> dict[str, str]:
    try:
        files = json.loads(path.read_text(encoding="utf-8")).get("files", {})
    except (OSError, ValueError, AttributeError):
        return {}
    return {str(k): str(v) for k, v in files.items()} if isinstance(files, dict) else {}


def _owned(out_dir: Path) -> dict[str, str]:
    """Every recording the demo's manifests list (one manifest per strategy folder, so the
    strategies' workers never write the same file)."""
    owned: dict[str, str] = {}
    for strategy in STRATEGIES:
        owned.update(_manifest_files(out_dir / strategy.lower() / MANIFEST))
    return owned


def clear_previous_run(out_dir: Path) -> int:
    """Remove the recordings a previous demo wrote into ``out_dir``, so it runs again in place.

    A recording is removed only when the demo's manifest lists it with the same content (sha256):
    a user's recording, or one changed since, is never touched, and the run is refused before
    anything is removed. Returns the number of files removed.
    """
    owned = _owned(out_dir)
    present = [p for p in recording_paths(out_dir) if p.exists()]
    for p in present:
        rel = p.relative_to(out_dir).as_posix()
        if owned.get(rel) != _sha256(p):
            raise ConfigError(
                "a recording thrustmap demo did not write (or one changed since) is here; "
                "it is kept: run the demo in another folder (thrustmap demo -o FOLDER)",
                file=str(p),
            )
    for p in present:
        p.unlink()
    return len(present)


def _remember(out_dir: Path, written: list[Path]) -> None:
    """Add ``written`` (with their content hashes) to the manifest of the strategy folder each
    lies in (``out_dir/sr/thrustmap-demo.json``)."""
    by_folder: dict[str, list[Path]] = {}
    for p in written:
        by_folder.setdefault(p.relative_to(out_dir).parts[0], []).append(p)
    for folder, paths in by_folder.items():
        manifest = out_dir / folder / MANIFEST
        files = _manifest_files(manifest)
        for p in paths:
            if p.exists():
                files[p.relative_to(out_dir).as_posix()] = _sha256(p)
        text = json.dumps({"written_by": "thrustmap demo", "files": files}, indent=2)
        atomic_write_text(manifest, text + "\n")


def experiments() -> dict[str, plans.Plan]:
    """The paper's Fig. 5 campaign, in % of 1000–2000 µs (1100–1600 µs steps, 1800 µs ramp top)."""
    return {
        "steps": plans.steps(15, 60, 5, low_pct=10, dwell_s=3.0, low_dwell_s=2.0),
        "stairs-up": plans.stairs(10, 60, 5, dwell_s=3.0),
        "stairs-down": plans.stairs(10, 60, 5, down=True, dwell_s=3.0),
        "ramp": plans.ramp(0, 70, duration_s=30.0),
    }


def sr_vs_mr(sr: ThrustMap, mr: ThrustMap) -> str:
    """One sentence: how much more command the MR map asks than SR, over the range both cover."""
    a, c = sr.validity, mr.validity
    t_lo, t_hi = max(a.thrust_n.lo, c.thrust_n.lo), min(a.thrust_n.hi, c.thrust_n.hi)
    b_lo, b_hi = max(a.voltage_v.lo, c.voltage_v.lo), min(a.voltage_v.hi, c.voltage_v.hi)
    if not (t_lo < t_hi and b_lo < b_hi):
        return "SR vs MR: the two maps share no thrust and voltage range to compare."
    t, b = np.meshgrid(np.linspace(t_lo, t_hi, 25), np.linspace(b_lo, b_hi, 5))
    pct = np.asarray(mr.throttle_pct(t.ravel(), b.ravel()), float) - np.asarray(
        sr.throttle_pct(t.ravel(), b.ravel()), float
    )
    scale = sr.throttle_scale
    diff = pct / 100.0 * (scale.hi - scale.lo)  # in SR's own unit
    unit = "µs" if scale.unit == "us" else scale.unit
    return (
        f"MR vs SR: {float(np.mean(diff)):+.1f} {unit} on average "
        f"({float(np.min(diff)):+.1f}..{float(np.max(diff)):+.1f}) for equal thrust and voltage."
    )


@dataclass
class StrategyResult:
    name: str
    logs: list[Path]
    runs: list[RunResult]
    map_path: Path
    tmap: ThrustMap
    in_sample: dict[str, tuple[float, float]] = field(default_factory=dict)  # paper method
    held_out: dict[str, float] = field(default_factory=dict)  # by-file, steady state
    truth: dict[str, float] = field(default_factory=dict)  # vs the simulator's true map


def truth_error_pct(tmap: ThrustMap, plant: PhysicsPlant, n: int = 40) -> float:
    """Mean |map − true map| in % throttle over the map's validity box (feasible points)."""
    v = tmap.validity
    tt, bb = np.meshgrid(
        np.linspace(v.thrust_n.lo, v.thrust_n.hi, n), np.linspace(v.voltage_v.lo, v.voltage_v.hi, n)
    )
    truth = plant.true_throttle_fraction(tt, bb) * 100.0
    ok = np.isfinite(truth)
    return float(np.mean(np.abs(tmap.throttle_pct(tt[ok], bb[ok], corrected=False) - truth[ok])))


def run_strategy(
    strategy: str, rotors: int, out_dir: Path, seed: int, say: Callable[[str], None]
) -> StrategyResult:
    """One strategy's campaign (the paper's four experiments) on its own simulated bench,
    fitted, and every model scored in-sample, held out by file and against the true map."""
    peers.reset_benches()
    clock = SimClock()
    bench = f"demo-{strategy.lower()}"
    fc = MspThrottleOutput(
        open_transport(
            f"sim://betaflight?bench={bench}&rotors={rotors}&seed={seed}&protocol=PWM",
            clock=clock,
            timeout=0,
        ),
        clock,
    )
    stand = TytoStand(
        open_transport(f"sim://tyto-1585?bench={bench}&drive_esc=0", clock=clock, timeout=0),
        clock,
        SIM_TYTO_CALIBRATION,
    )
    plant = peers.bench_plant({"bench": bench})
    logs, runs = [], []
    limits = Limits(max_current_a=120.0, max_throttle_pct=75.0)
    with fc, stand:
        for name, plan in experiments().items():
            path = out_dir / strategy.lower() / f"xnova-{strategy}-{name}.csv"
            path.parent.mkdir(parents=True, exist_ok=True)
            run = record_sweep(
                plan,
                fc,
                stand,
                str(path),
                clock,
                limits=limits,
                config=RunConfig(rotors_on_esc=rotors),
                meta={"simulated": True},
            )
            say(
                f"{strategy} {name:<11} {run.status}: {run.samples} samples, {run.duration_s:.0f} s simulated"
            )
            logs.append(path)
            runs.append(run)
            _remember(out_dir, [path, path.with_suffix(".meta.json")])
            if run.interrupted:  # Ctrl-C/SIGTERM stops the demo: nothing fitted on part
                raise KeyboardInterrupt(
                    f"{strategy} {name} sweep stopped ({run.reason}); no map fitted and no "
                    f"report written (partial logs in {path.parent})"
                )
    datasets = load_datasets(logs)
    outcome = fit_map(datasets)
    map_path = out_dir / f"{strategy.lower()}-map.json"
    outcome.map.save(map_path)
    res = StrategyResult(strategy, logs, runs, map_path, outcome.map)
    paper_sel = Selection(all_samples=True, throttle_range=(1300, 1500), thrust_range=(0, 11))
    for row in compare(datasets, MODELS, "in-sample", selection=paper_sel):
        res.in_sample[row.model] = (row.inside.mean_pct, row.inside.std_pct)
    for row in compare(datasets, MODELS, "by-file"):
        res.held_out[row.model] = row.all.mean_pct  # every held-out point
    for model in MODELS:
        res.truth[model] = truth_error_pct(fit_map(datasets, model=model).map, plant)
    return res


def _strategy_worker(
    conn: Connection,
    strategy: str,
    rotors: int,
    out_dir: Path,
    seed: int,
    say: Callable[[str], None],
    with_report: bool,
) -> None:
    """A forked worker: one strategy (and its report); sends ("ok", result) or ("error", exc)."""
    try:
        res = run_strategy(strategy, rotors, out_dir, seed, say)
        if with_report:
            _write_report(str(res.map_path), [str(p) for p in res.logs], str(report_path(res)))
        conn.send(("ok", res))
    except BaseException as exc:  # reported to the parent, which raises it
        try:
            conn.send(("error", exc))
        except Exception:  # an exception that does not pickle: its text
            conn.send(("error", RuntimeError(f"{type(exc).__name__}: {exc}")))
    finally:
        conn.close()


def _parallel_ok() -> bool:
    import multiprocessing as mp

    return (os.cpu_count() or 1) > 1 and "fork" in mp.get_all_start_methods()


def run_demo(
    out_dir: Path,
    *,
    seed: int = 1,
    progress: Callable[[str], None] | None = None,
    reports: bool = False,
    parallel: bool | None = False,
) -> list[StrategyResult]:
    """The paper's campaign for each strategy (SR, MR), fitted and scored; with ``reports``, an
    HTML report beside each map (:func:`report_path`).

    The strategies are independent (each its own simulated bench, clock and seed), so with
    ``parallel`` each runs in a forked worker process and the demo takes about as long as one
    (None: when there are two or more cores and ``fork``, as the CLI asks; the default False
    runs them here, in turn, as a caller with threads of its own needs). The results are the
    same either way. Leaving early (an error, Ctrl-C) stops every worker.
    """
    say = progress or (lambda _msg: None)
    out_dir.mkdir(parents=True, exist_ok=True)
    if removed := clear_previous_run(out_dir):
        say(f"replacing the previous demo's {removed} files in {out_dir}")
    if parallel is None:
        parallel = _parallel_ok()
    if not parallel:
        results = []
        for strategy, rotors in STRATEGIES.items():
            res = run_strategy(strategy, rotors, out_dir, seed, say)
            if reports:
                _write_report(str(res.map_path), [str(p) for p in res.logs], str(report_path(res)))
            results.append(res)
        return results
    import multiprocessing as mp

    ctx = mp.get_context("fork")
    workers = []
    try:
        for strategy, rotors in STRATEGIES.items():
            receive, send = ctx.Pipe(duplex=False)
            proc = ctx.Process(
                target=_strategy_worker,
                args=(send, strategy, rotors, out_dir, seed, say, reports),
                name=f"thrustmap-demo-{strategy.lower()}",
            )
            proc.start()
            send.close()  # the worker holds the sending end: EOF here when it dies
            workers.append((strategy, receive, proc))
        results = []
        for strategy, receive, proc in workers:
            try:
                kind, value = receive.recv()
            except EOFError:
                proc.join()
                raise RuntimeError(
                    f"the demo's {strategy} worker ended without a result (exit {proc.exitcode})"
                ) from None
            if kind != "ok":
                raise value
            results.append(value)
        return results
    finally:
        for _, receive, proc in workers:
            if proc.is_alive():
                proc.join(timeout=5.0)
            if proc.is_alive():
                proc.terminate()
                proc.join()
            receive.close()


def report(results: list[StrategyResult], out_dir: Path, cols: int | None = None) -> str:
    """The comparison as text: one table with a column group per strategy, or, when that is
    wider than ``cols`` (the terminal's width), one table per strategy."""
    from thrustmap.cli.textwidth import table

    lines = ["Thrust-map errors, % of the 1000–2000 µs range (simulated xNova 2207 on 6S)", ""]
    right = [False] + [True] * (3 * len(results))

    def cells(r: StrategyResult, m: str) -> list[str]:
        mean, std = r.in_sample[m]
        return [f"{mean:.3f} ± {std:.3f}", f"{r.held_out[m]:.3f}", f"{r.truth[m]:.3f}"]

    def heads(r: StrategyResult) -> list[str]:
        return [f"{r.name} in-sample", f"{r.name} held-out", f"{r.name} vs truth"]

    wide = table(
        ["model", *(h for r in results for h in heads(r))],
        [[m, *(c for r in results for c in cells(r, m))] for m in MODELS],
        right=right,
        cols=10_000,
    )
    if cols is None or max(len(line) for line in wide.splitlines()) <= cols:
        lines.append(wide)
    else:
        for i, r in enumerate(results):
            rows = [[m, *cells(r, m)] for m in MODELS]
            lines += [""] if i else []
            lines.append(table(["model", *heads(r)], rows, right=right[:4], cols=cols))
    lines += [
        "",
        "in-sample: the paper's method (all samples, 1300 < µs < 1500, 0 < T < 11 N, least squares);",
        "held-out: leave-one-experiment-out on steady-state points; vs truth: the fitted map against",
        "the simulator's true map over the swept box.",
    ]
    by = {r.name: r for r in results}
    if "SR" in by and "MR" in by:
        lines += ["", sr_vs_mr(by["SR"].tmap, by["MR"].tmap)]
    lines += ["", f"Files in {out_dir}/:"]
    for r in results:
        lines.append(
            f"  {r.name}: {', '.join(str(p.relative_to(out_dir)) for p in r.logs)}; map {r.map_path.name}"
        )
    if results:
        v = results[0].tmap.validity
        b = round(0.5 * (v.voltage_v.lo + v.voltage_v.hi), 1)
        t = round(0.5 * v.thrust_n.hi, 1)
        lines.append(
            f"Try: thrustmap predict {results[0].map_path} --thrust-n {t:g} --voltage-v {b:g}"
        )
    return "\n".join(lines)


def report_path(result: StrategyResult) -> Path:
    """Where the HTML report of ``result``'s map goes: beside the map."""
    return result.map_path.with_name(result.map_path.stem + "-report.html")


def _write_report(map_path: str, logs: list[str], out: str) -> str:
    from thrustmap.report.data import build
    from thrustmap.report.html import write_report

    write_report(build(map_path, logs), out)
    return out


def write_reports(results: list[StrategyResult]) -> list[Path]:
    """An HTML report next to each map (``thrustmap report``), returned in order (what
    ``run_demo(reports=True)`` writes; benchmarks/bench_demo.py times it on its own)."""
    for r in results:
        _write_report(str(r.map_path), [str(p) for p in r.logs], str(report_path(r)))
    return [report_path(r) for r in results]
