"""Cross-voltage benchmark: a map fitted at one battery voltage, scored at another.

Over the third-party stand data (``../shared/data/third-party-stands``, not shipped with the
project): for every motor × propeller pair in ``strawson-5inch`` (each recorded on 2S and 3S),
fit a map on one voltage's file exactly as ``thrustmap fit FILE`` does (default selection,
default model) and score ALL points of the other file as ``thrustmap evaluate`` does (inside
and outside the map's validity box together), both ways: 48 pairs × 2 = 96 directions. The same
is done for the seed paper's models (la, linear, poly2, poly2-trunc, poly3) side by side, and
the seed paper's own xNova data is scored by file (each step file predicting the other).

Every direction is also printed beside the default map's figure BEFORE issue 18 (physical
bounds, supported region; ``baselines/cross_voltage_pre_issue18.csv``), with the directions now
worse counted: issue 18's acceptance is "no direction worse than before". The point sets differ
where selection changed since (n then and now are printed).

Run: python benchmarks/bench_cross_voltage.py [--per-pair] [--data DIR]
"""

from __future__ import annotations

import argparse
import logging
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from thrustmap.core.errors import FitError, ThrustmapError
from thrustmap.fitting.dataset import Dataset
from thrustmap.fitting.fit.backemf import backemf_rows
from thrustmap.fitting.fit.fitmap import fit_map
from thrustmap.fitting.fit.validation import evaluate
from thrustmap.fitting.loaders.load import load_datasets
from thrustmap.fitting.metrics import ErrorStats, coverage, error_stats
from thrustmap.fitting.models import MODELS as MODEL_DEFS
from thrustmap.fitting.models import backemf_coefficients
from thrustmap.fitting.names import DEFAULT_MODEL
from thrustmap.fitting.selection.options import Selection
from thrustmap.fitting.selection.points import select

SHARED = Path(__file__).resolve().parent.parent.parent / "shared" / "data"
BASELINES = ("la", "linear", "poly2", "poly2-trunc", "poly3")
MODELS = (DEFAULT_MODEL, *BASELINES)
BACKEMF = "back-EMF"  # motor form identified from the training file's rpm and current
BASELINE = Path(__file__).resolve().parent / "baselines" / "cross_voltage_pre_issue18.csv"
#: a direction is "worse" when its figure exceeds the baseline's by more than rounding
WORSE_PP = 0.005


@dataclass
class Direction:
    train: str
    test: str
    errors: dict[str, ErrorStats | None]  # None: the model could not be fitted
    note: str = ""  # the default fit's identification line
    fallback: bool = False  # default selection found no points, all samples used


def _selection_for(ds: Dataset) -> tuple[Selection, bool]:
    """The default selection, as ``thrustmap fit FILE`` uses it. Fallback (before step-summary
    exports were accepted by the default selection): when it finds no steady-state points the
    file's rows are taken as they are, which for a step summary are already steady points."""
    try:
        select(ds, Selection())  # the default selection, exactly as `fit` runs it
    except FitError as exc:
        if "no steady-state points" not in str(exc):
            raise
        return Selection(all_samples=True), True
    return Selection(), False


def score(train: Dataset, test: Dataset, model: str) -> tuple[ErrorStats | None, str, bool]:
    sel_train, fb_train = _selection_for(train)
    sel_test, fb_test = _selection_for(test)
    try:
        out = fit_map([train], model=model, selection=sel_train)
    except ThrustmapError:
        return None, "", fb_train
    (row,) = evaluate(out.map, [test], sel_test)
    note = out.map.identification.get("reason", "") if out.map.identification else ""
    return row.all, note, fb_train or fb_test


def score_backemf(train: Dataset, test: Dataset) -> ErrorStats | None:
    """The ``motor`` form identified from the training file's rpm and current (B·d = Ke·ω + R·I)
    instead of from thrust alone, scored like the default: what ``fit`` would get if it used
    the back-EMF scaling from one voltage (it does not: nothing held out could confirm it)."""
    rows = backemf_rows(train, Selection())
    coef = None if rows is None else backemf_coefficients(*rows)
    if coef is None:
        return None
    sel, _ = _selection_for(test)
    p = select(test, sel)
    return error_stats(MODEL_DEFS["motor"].evaluate(coef, p.thrust_n, p.voltage_v), p.throttle_pct)


def cross_voltage(folder: Path) -> list[Direction]:
    out: list[Direction] = []
    for low in sorted(folder.glob("*_7.csv")):
        high = low.with_name(low.name.replace("_7.csv", "_11.csv"))
        if not high.exists():
            continue
        a, b = load_datasets([str(low), str(high)])
        for train, test in ((a, b), (b, a)):
            d = Direction(train.name, test.name, {})
            for model in MODELS:
                stats, note, fb = score(train, test, model)
                d.errors[model] = stats
                if model == DEFAULT_MODEL:
                    d.note, d.fallback = note, fb
            d.errors[BACKEMF] = score_backemf(train, test)
            out.append(d)
    return out


def summary(values: list[float]) -> str:
    if not values:
        return "      -       -"
    v = np.asarray(values)
    return f"{np.median(v):7.2f} {np.percentile(v, 90):7.2f}"


def xnova_by_file(root: Path) -> list[str]:
    sr = root / "xnova-thrust-stand" / "single_rotor"
    files = [sr / "xNova-SR-steps.csv", sr / "xNova-SR-steps-up.csv"]
    if not all(f.exists() for f in files):
        return ["xNova: data not found"]
    lines = [
        "xNova SR by file (fit one step file, score the other; default selection), mean e_Th %:",
        f"  {'model':<12} {'inside box':>10} {'n':>4} {'all points':>10} {'n':>4} {'p95 all':>8}",
    ]
    ds = load_datasets([str(f) for f in files])
    for model in MODELS:
        pred_in: list[ErrorStats] = []
        pred_all: list[ErrorStats] = []
        for i in range(2):
            out = fit_map([ds[i]], model=model)
            (row,) = evaluate(out.map, [ds[1 - i]])
            pred_in.append(row.inside)
            pred_all.append(row.all)
        n_in = sum(s.n for s in pred_in)
        n_all = sum(s.n for s in pred_all)
        mean_in = sum(s.mean_pct * s.n for s in pred_in if s.n) / n_in if n_in else float("nan")
        mean_all = sum(s.mean_pct * s.n for s in pred_all) / n_all
        p95 = max(s.p95_pct for s in pred_all)
        lines.append(
            f"  {model:<12} {mean_in:>10.3f} {n_in:>4} {mean_all:>10.3f} {n_all:>4} {p95:>8.2f}"
        )
    return lines


# -- coverage of the default map's 95 % interval ------------------------------------------------

#: Strawson motors the interval's voltage term κ is calibrated on; d-f are held out
CALIBRATION_MOTORS = ("a", "b", "c")
COVERAGE_GOAL_PCT = 90.0


@dataclass
class Scored:
    """One map scored on one file, per point: |error|, the interval's parts without κ (base,
    widening factor), |ln(B/B_edge)|, and whether the point is inside the supported region."""

    err: np.ndarray
    base: np.ndarray
    factor: np.ndarray
    rho: np.ndarray
    inside: np.ndarray
    kappa: float  # the map's own κ

    def half(self, kappa: float | None = None) -> np.ndarray:
        k = self.kappa if kappa is None else kappa
        return np.sqrt(self.base**2 + (k * self.rho) ** 2) * self.factor


def scored(train: Dataset, test: Dataset) -> Scored:
    """Fit ``train`` as ``thrustmap fit`` does, score ``test`` as ``thrustmap evaluate`` does."""
    sel_train, _ = _selection_for(train)
    sel_test, _ = _selection_for(test)
    tmap = fit_map([train], selection=sel_train).map
    p = select(test, sel_test)
    pred = tmap.throttle_pct(p.thrust_n, p.voltage_v, corrected=False)
    no_kappa = replace(tmap, interval={**tmap.interval, "voltage_pct_per_log": 1e-12})
    parts = no_kappa.interval_parts(p.thrust_n, p.voltage_v)
    assert parts is not None
    base, factor, _ = parts
    region = tmap.supported_region()
    iv = tmap.prediction_interval()
    assert iv is not None
    return Scored(
        err=np.abs(pred - p.throttle_pct),
        base=np.asarray(base),
        factor=np.asarray(factor),
        rho=iv.voltage_log_distance(p.thrust_n, p.voltage_v),
        inside=np.asarray(region.contains(p.thrust_n, p.voltage_v)),
        kappa=float(tmap.interval.get("voltage_pct_per_log", 0.0)),
    )


def coverage_line(name: str, runs: list[Scored], kappa: float | None = None) -> tuple[str, bool]:
    """'name  inside x % of n (median ±w)  outside ...' and whether both meet the goal."""
    err = np.concatenate([r.err for r in runs])
    half = np.concatenate([r.half(kappa) for r in runs])
    inside = np.concatenate([r.inside for r in runs])
    cells = []
    met = True
    for label, m in (("inside", inside), ("outside", ~inside)):
        c = coverage(err[m], np.zeros(int(m.sum())), half[m])
        cells.append(f"{label} {c.describe():<32}")
        met &= not c.n or c.coverage_pct >= COVERAGE_GOAL_PCT
    return f"  {name:<40} " + " ".join(cells), met


def strawson_scored(folder: Path) -> dict[tuple[str, str], list[Scored]]:
    """(motor letter, '2S->3S' or '3S->2S') -> the pairs' scores."""
    out: dict[tuple[str, str], list[Scored]] = {}
    for low in sorted(folder.glob("*_7.csv")):
        high = low.with_name(low.name.replace("_7.csv", "_11.csv"))
        if not high.exists():
            continue
        a, b = load_datasets([str(low), str(high)])
        out.setdefault((low.name[0], "2S->3S"), []).append(scored(a, b))
        out.setdefault((low.name[0], "3S->2S"), []).append(scored(b, a))
    return out


def calibrate_kappa(runs: list[Scored], level: float = 95.0) -> float:
    """The smallest κ (% per unit |ln(B/B_edge)|, in steps of 0.5) whose interval covers
    ``level`` % of the points."""
    for kappa in np.arange(0.0, 80.0, 0.5):
        err = np.concatenate([r.err for r in runs])
        half = np.concatenate([r.half(float(kappa)) for r in runs])
        if 100.0 * float(np.mean(err <= half)) >= level:
            return float(kappa)
    return float("nan")


def creeping_staircases(seeds: tuple[int, ...] = (1, 2, 3)) -> list[Scored]:
    """Simulated Crazyflie staircases with 1 s stairs on a creeping load cell: the map of each
    log scored on the other logs (the same motor recorded again)."""
    import tempfile

    from thrustmap.fitting.loaders.load import load_dataset
    from thrustmap.rig.sim.physics import LoadCellCreep
    from thrustmap.rig.sim.sysid import simulate_staircase, write_csv

    with tempfile.TemporaryDirectory() as tmp:
        logs = [
            load_dataset(
                write_csv(
                    simulate_staircase(
                        seed=s, levels=8, dwell_s=1.0, cell_update_s=0.1, creep=LoadCellCreep()
                    ),
                    Path(tmp) / f"creep{s}.csv",
                )
            )
            for s in seeds
        ]
    return [scored(a, b) for a in logs for b in logs if a is not b]


def coverage_report(root: Path, calibrate: bool) -> list[str]:
    lines = [
        "coverage of the default map's 95 % interval (share of the other file's points inside "
        "it; goal >= 90 % inside and outside the supported region), median half-width beside:"
    ]
    met_all = True
    sr = root / "xnova-thrust-stand" / "single_rotor"
    files = [sr / "xNova-SR-steps.csv", sr / "xNova-SR-steps-up.csv"]
    if all(f.exists() for f in files):
        ds = load_datasets([str(f) for f in files])
        line, met = coverage_line("xNova SR by file", [scored(ds[0], ds[1]), scored(ds[1], ds[0])])
        lines.append(line)
        met_all &= met
    folder = root / "third-party-stands" / "strawson-5inch"
    if folder.is_dir():
        by = strawson_scored(folder)
        ways = ("2S->3S", "3S->2S")
        cal = [r for (m, _), rs in by.items() if m in CALIBRATION_MOTORS for r in rs]
        held = [r for (m, _), rs in by.items() if m not in CALIBRATION_MOTORS for r in rs]
        kappa = cal[0].kappa if cal else 0.0
        for way in ways:
            runs = [r for (_, w), rs in by.items() if w == way for r in rs]
            line, met = coverage_line(f"Strawson a-f {way} ({len(runs)} pairs)", runs)
            lines.append(line)
            met_all &= met
        for name, runs in (("a-c (calibration)", cal), ("d-f (held out)", held)):
            lines.append(coverage_line(f"Strawson {name}, both ways", runs)[0])
        if calibrate:
            fitted = calibrate_kappa(cal)
            lines.append(
                f"  calibration: kappa covering 95 % of motors {'-'.join(CALIBRATION_MOTORS[::2])} "
                f"= {fitted:g} % per unit |ln(B/B_edge)| (the map uses {kappa:g}); with it, "
                f"held-out d-f: {coverage_line('', held, fitted)[0].strip()}"
            )
    line, met = coverage_line("simulated creeping 1 s staircases by file", creeping_staircases())
    lines.append(line)
    met_all &= met
    lines.append(
        f"  goal (>= {COVERAGE_GOAL_PCT:g} % inside and outside, every set): "
        f"{'met' if met_all else 'NOT met'}"
    )
    return lines


def load_baseline(path: Path = BASELINE) -> dict[tuple[str, str], tuple[float, int]]:
    """(train, test) -> (mean e_Th %, points scored) of the pre-issue-18 default map."""
    out: dict[tuple[str, str], tuple[float, int]] = {}
    if not path.exists():
        return out
    for line in path.read_text(encoding="utf-8").splitlines():
        if not line or line.startswith("#") or line.startswith("train,"):
            continue
        train, test, value, n = line.split(",")
        out[(train, test)] = (float(value), int(n))
    return out


def baseline_table(
    dirs: list[Direction], base: dict[tuple[str, str], tuple[float, int]]
) -> list[str]:
    """Every direction: the default map now beside the pre-issue-18 figure, worse ones flagged."""
    lines = [
        f"per direction, default '{DEFAULT_MODEL}' now vs before issue 18 (mean e_Th %, all points):",
        f"  {'train':<9} {'test':<9} {'now':>6} {'n':>3} {'before':>7} {'n':>3} {'delta':>6}",
    ]
    worse: list[float] = []
    now_vals: list[float] = []
    then_vals: list[float] = []
    for d in dirs:
        s = d.errors[DEFAULT_MODEL]
        b = base.get((d.train, d.test))
        if s is None or b is None:
            continue
        delta = s.mean_pct - b[0]
        flag = "  WORSE" if delta > WORSE_PP else ""
        if flag:
            worse.append(delta)
        now_vals.append(s.mean_pct)
        then_vals.append(b[0])
        lines.append(
            f"  {d.train:<9} {d.test:<9} {s.mean_pct:>6.2f} {s.n:>3} {b[0]:>7.2f} {b[1]:>3} "
            f"{delta:>+6.2f}{flag}"
        )
    if now_vals:
        lines.append(
            f"  {len(now_vals)} directions: median {np.median(now_vals):.2f} % now, "
            f"{np.median(then_vals):.2f} % before; {len(worse)} worse than before"
            + (f" (by up to {max(worse):.2f} pp)" if worse else "")
        )
    return lines


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=SHARED, help="the shared data folder")
    ap.add_argument("--per-pair", action="store_true", help="print every direction")
    ap.add_argument(
        "--calibrate",
        action="store_true",
        help="also fit the interval's voltage term kappa on motors a-c and score d-f with it",
    )
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    folder = args.data / "third-party-stands" / "strawson-5inch"
    if not folder.is_dir():
        print(f"data not found: {folder}", file=sys.stderr)
        return 2
    dirs = cross_voltage(folder)
    if args.per_pair:
        head = f"{'train':<9} {'test':<9}" + "".join(f" {m:>11}" for m in (*MODELS, BACKEMF))
        print(head)
        for d in dirs:
            cells = "".join(
                f" {'fail':>11}" if (s := d.errors[m]) is None else f" {s.mean_pct:>11.2f}"
                for m in (*MODELS, BACKEMF)
            )
            print(f"{d.train:<9} {d.test:<9}{cells}{'  (all samples)' if d.fallback else ''}")
            print(f"    {DEFAULT_MODEL}: {d.note}")
        print()
    print(
        f"strawson-5inch, {len(dirs)} directions (fit on one voltage with defaults, score ALL "
        "points of the other), mean e_Th % per direction:"
    )
    print(f"  {'model':<12} {'median':>7} {'p90':>7} {'max':>7} {'failed':>6}")
    for m in (*MODELS, BACKEMF):
        vals = [s.mean_pct for d in dirs if (s := d.errors[m]) is not None]
        failed = sum(1 for d in dirs if d.errors[m] is None)
        mx = f"{max(vals):7.2f}" if vals else "      -"
        tag = (
            " (default)"
            if m == DEFAULT_MODEL
            else " (motor from rpm+current; not used by fit at one voltage)"
            if m == BACKEMF
            else ""
        )
        print(f"  {m:<12} {summary(vals)} {mx} {failed:>6}{tag}")
    n_fb = sum(d.fallback for d in dirs)
    if n_fb:
        print(
            f"  note: default selection found no steady-state points in {n_fb} directions; "
            "their rows (one averaged row per step) were used as they are"
        )
    vals = [s.mean_pct for d in dirs if (s := d.errors[DEFAULT_MODEL]) is not None]
    ok = (
        len(vals) == len(dirs)
        and float(np.median(vals)) <= 3.0
        and float(np.percentile(vals, 90)) <= 6.0
    )
    print(
        f"  goal (default median <= 3.0 %, p90 <= 6.0 %, every pair fits): {'met' if ok else 'NOT met'}"
    )
    base = load_baseline()
    if base:
        print()
        for line in baseline_table(dirs, base):
            print(line)
    print()
    for line in xnova_by_file(args.data):
        print(line)
    print()
    for line in coverage_report(args.data, args.calibrate):
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
