"""Extrapolation benchmark: how wrong a map is, and how often its 95 % interval holds, at each
distance outside its supported region.

On every rig we have, a map is fitted exactly as ``thrustmap fit`` does and scored on points it
never saw, three ways:
- thrust: fitted on the part of a recording below 50, 60 or 70 % of the thrust it reached (the
  recording cut at the command where it stopped, as a stand run that stopped lower), scored on
  the whole recording;
- voltage: fitted on a recording at one battery voltage, scored on the same rotor at another;
- recording: fitted on one recording, scored on a second recording of the same rotor.
Each held-out point is binned by its distance outside the map's supported region: when it lies
away from the voltages measured near its thrust, by ρ = |ln(B / B_measured)| (bins of
``VOLTAGE_BIN``), else by the thrust ratio T / reach at B (the thrust the data reached there,
bins of ``THRUST_BIN``); points inside the region form their own row. Per rig and bin: n, the
median |error| (% throttle) and the share inside the interval, with this branch's growth beyond
the reach and with main 19a0a12's (``growth_per_span``, the per-map growth learned from the
map's own folds, at least 0.5 per thrust span) beside it.

Rigs. SET ASIDE before any result was looked at (never used to tune; scored and printed apart):
the xNova multirotor (MR) data, Strawson motors d-f (already κ's held-out motors), simulator
seeds 4-6 of both simulated rigs, and the public RCbenchmark recordings of
diegosdantonio/thruststand_test (``--public DIR``: its ``datasets`` folder; not shipped).
TUNED ON: xNova single rotor (SR), Strawson motors a-c, simulator seeds 1-3.

``--calibrate`` prints the smallest growth that holds >= 90 % of the tuning rigs' points in
every bin up to the limit (thrust bins to ``EVIDENCE_LIMIT_THRUST_RATIO``); ``--table`` prints
the tuning rigs' bins as ``fitting.extrapolation.EVIDENCE`` rows.

Run: python benchmarks/bench_extrapolation.py [--data DIR] [--public DIR] [--calibrate] [--table]
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

import thrustmap.fitting.extrapolation as extrapolation
from thrustmap.core.errors import FitError, ThrustmapError
from thrustmap.core.units import ThrottleScale
from thrustmap.fitting.dataset import STEP_SUMMARY, Dataset
from thrustmap.fitting.extrapolation import (
    COVERAGE_GOAL_PCT,
    EVIDENCE_LIMIT_THRUST_RATIO,
    EVIDENCE_LIMIT_VOLTAGE_LOG,
    EXTRAPOLATION_GROWTH,
    RECORDING_FACTOR,
    THRUST_BIN,
    VOLTAGE_BIN,
)
from thrustmap.fitting.fit.fitmap import fit_map
from thrustmap.fitting.interval import VOLTAGE_EXTRAPOLATION_PCT
from thrustmap.fitting.loaders.load import load_datasets
from thrustmap.fitting.mapfile import ThrustMap
from thrustmap.fitting.selection.options import Selection
from thrustmap.fitting.selection.points import Points, select

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))  # support.public_data: the manifest's files by name
from support import public_data as pd  # noqa: E402

SHARED = Path(
    os.environ.get("THRUSTMAP_SHARED_DATA")
    or Path(__file__).resolve().parent.parent.parent / "shared" / "data"
)
FRACTIONS = (0.5, 0.6, 0.7)
TUNE_STRAWSON = ("a", "b", "c")
TUNE_SEEDS = (1, 2, 3)
ASIDE_SEEDS = (4, 5, 6)
MIN_BIN_POINTS = 10  # a bin with fewer points is printed but is not evidence
#: main 19a0a12's κ: the baseline column is main's interval (its growth per thrust span, this
#: κ, no second-recording term) on this branch's fit (q as learned here)
MAIN_KAPPA_PCT = 12.5


@dataclass
class Recording:
    rig: str
    rotor: str  # recordings with one key are the same rotor
    ds: Dataset
    aside: bool
    label: str = ""  # e.g. the pack: recordings of a rotor with different labels differ in B


@dataclass
class Scored:
    """One map scored on held-out points."""

    rig: str
    aside: bool
    kind: str  # "thrust", "voltage", "recording"
    err: np.ndarray
    base: np.ndarray  # the interval before growth
    base_main: np.ndarray  # the same as main had it (no second-recording term)
    d_span: np.ndarray  # main's distance: beyond the thrust range, in thrust spans
    excess: np.ndarray  # this branch's: beyond the thrust range, in reaches
    ratio: np.ndarray  # T / reach at B
    rho: np.ndarray  # |ln(B / B_measured)|
    inside: np.ndarray
    growth_main: float
    growth_own: float  # what the map's own folds showed, per reach (0: none)
    q_pct: float  # the map's held-out quantile q
    one_file: bool  # fitted on one recording: carries the second-recording term

    def half(
        self,
        growth: float | None,
        factor: float = RECORDING_FACTOR,
        kappa: float = VOLTAGE_EXTRAPOLATION_PCT,
    ) -> np.ndarray:
        """The interval with this growth (None: main's growth per span, and no
        second-recording term), second-recording factor and κ."""
        if growth is None:
            return self.base_main * (1.0 + self.growth_main * self.d_span)
        extra = (kappa**2 - VOLTAGE_EXTRAPOLATION_PCT**2) * self.rho**2
        if self.one_file:
            extra = extra + self.q_pct**2 * (factor**2 - RECORDING_FACTOR**2)
        base = np.sqrt(np.maximum(self.base**2 + extra, 0.0))
        return base * (1.0 + max(growth, self.growth_own) * np.sqrt(self.excess))


@dataclass
class Table:
    scored: list[Scored] = field(default_factory=list)
    failed: int = 0


# -- selection and fitting ----------------------------------------------------------------------


def selection_for(ds: Dataset) -> Selection:
    """The default selection; a step summary (or a cut of one) is taken row by row."""
    if ds.meta.get("layout") == STEP_SUMMARY:
        return Selection(all_samples=True)
    try:
        select(ds, Selection())
    except FitError as exc:
        if "no steady-state points" not in str(exc):
            raise
        return Selection(all_samples=True)
    return Selection()


def points_of(ds: Dataset) -> Points:
    return select(ds, selection_for(ds))


def fit(ds: Dataset) -> tuple[ThrustMap, float]:
    """The map ``thrustmap fit`` writes, and the growth per reach its own folds showed."""
    saved = extrapolation.EXTRAPOLATION_GROWTH
    # read the map's own growth, unfloored (interval.py reads the floor from its module at each
    # call; it once held its own binding, and lowering it here changed nothing)
    extrapolation.EXTRAPOLATION_GROWTH = 1e-9
    try:
        own = fit_map([ds], selection=selection_for(ds)).map
    finally:
        extrapolation.EXTRAPOLATION_GROWTH = saved
    iv = own.prediction_interval()
    g_own = iv.growth_per_reach if iv is not None and iv.growth_per_reach > 1e-6 else 0.0
    tmap = fit_map([ds], selection=selection_for(ds)).map
    return tmap, g_own


def score(rec: Recording, tmap: ThrustMap, g_own: float, test: Points, kind: str) -> Scored:
    iv = tmap.prediction_interval()
    if iv is None:
        raise FitError("no interval")
    t, b = test.thrust_n, test.voltage_v
    pred = tmap.throttle_pct(t, b, corrected=False)
    base, _, _ = iv.parts(t, b, tmap.model_def.design(t, b))
    region = iv.region
    rec_pct = iv.recording_pct
    return Scored(
        rig=rec.rig,
        aside=rec.aside,
        kind=kind,
        err=np.abs(pred - test.throttle_pct),
        base=np.asarray(base),
        base_main=np.sqrt(
            np.maximum(
                np.asarray(base) ** 2
                - rec_pct**2
                - (iv.voltage_pct_per_log**2 - MAIN_KAPPA_PCT**2)
                * iv.voltage_log_distance(t, b) ** 2,
                0.0,
            )
        ),
        d_span=region.thrust_distance(t, b, iv.thrust_unit_n),
        excess=region.reach_excess(t, b),
        ratio=region.reach_ratio(t, b),
        rho=iv.voltage_log_distance(t, b),
        inside=np.asarray(region.contains(t, b)),
        growth_main=iv.growth_per_span,
        growth_own=g_own,
        q_pct=iv.half_width_pct,
        one_file=iv.recording_pct > 0,
    )


def cut_below(ds: Dataset, pts: Points, fraction: float) -> tuple[Dataset, Points] | None:
    """The recording as if the run had stopped at the command where its thrust passed
    ``fraction`` of the top thrust it reached, and the points it never reached (above that
    command); None: too few points below."""
    keep = pts.thrust_n <= fraction * float(np.max(pts.thrust_n))
    if keep.sum() < 4:
        return None
    top_pct = float(np.max(pts.throttle_pct[keep]))
    mask = ds.throttle_pct <= top_pct + 1e-9
    above = pts.throttle_pct > top_pct + 1e-9
    rest = replace(
        pts,
        thrust_n=pts.thrust_n[above],
        voltage_v=pts.voltage_v[above],
        throttle_pct=pts.throttle_pct[above],
        kind=pts.kind[above],
        roles=None,
        leg=None,
    )
    return ds.subset(np.asarray(mask)), rest


def experiments(recs: list[Recording], table: Table) -> None:
    """All three experiments on one rig's recordings."""
    pts = {id(r): points_of(r.ds) for r in recs}
    for r in recs:
        for f in FRACTIONS:
            cut = cut_below(r.ds, pts[id(r)], f)
            if cut is None:
                table.failed += 1
                continue
            _run(table, r, cut[0], cut[1], "thrust")
    for a in recs:
        for b in recs:
            if a is b or a.rotor != b.rotor:
                continue
            kind = "voltage" if a.label != b.label else "recording"
            _run(table, a, a.ds, pts[id(b)], kind)


def _run(table: Table, rec: Recording, train: Dataset, test: Points, kind: str) -> None:
    try:
        tmap, g_own = fit(train)
        table.scored.append(score(rec, tmap, g_own, test, kind))
    except ThrustmapError:
        table.failed += 1


# -- rigs ---------------------------------------------------------------------------------------


def xnova(root: Path) -> Iterator[Recording]:
    base = root / "xnova-thrust-stand"
    for rig, folder, names, aside in (
        (
            "xNova SR",
            "single_rotor",
            ("xNova-SR-steps", "xNova-SR-steps-up", "xNova-SR-ramp"),
            False,
        ),
        ("xNova MR", "multirotor", ("xNova-MR-steps", "xNova-MR-ramp"), True),
    ):
        files = [base / folder / f"{n}.csv" for n in names]
        if all(f.exists() for f in files):
            for ds in load_datasets([str(f) for f in files]):
                yield Recording(rig, rig, ds, aside, "6S")


def strawson(root: Path) -> Iterator[Recording]:
    folder = root / "third-party-stands" / "strawson-5inch"
    for low in sorted(folder.glob("*_7.csv")):
        high = low.with_name(low.name.replace("_7.csv", "_11.csv"))
        if not high.exists():
            continue
        aside = low.name[0] not in TUNE_STRAWSON
        rig = "Strawson d-f" if aside else "Strawson a-c"
        for ds, label in zip(load_datasets([str(low), str(high)]), ("2S", "3S"), strict=True):
            yield Recording(rig, low.name[:2], ds, aside, label)


#: the simulated 6S rig: its pack voltages at rest (V) per recording; 4S is a second pack
SIM_PACKS = (("6S full", 25.0), ("6S low", 22.4), ("4S", 16.4))
PWM = ThrottleScale("pwm", 1000.0, 2000.0, "us")


def sim_xnova(seed: int) -> Iterator[Recording]:
    """Step summaries of the xNova 6S preset with a 1 V ESC drop, the pack's sag, and a load
    cell with a per-recording scale error (±1 %) and offset (±0.02 N) and 0.5 % noise."""
    from thrustmap.rig.sim.physics import operating_point
    from thrustmap.rig.sim.presets import preset

    params = replace(preset("xnova-2207-6s"), esc_drop_v=1.0)
    rng = np.random.default_rng(seed)
    u = np.linspace(0.08, 1.0, 24)
    for label, ocv in SIM_PACKS:
        v = np.full_like(u, ocv)
        for _ in range(4):  # sag: the pack's 20 mΩ per cell under the motor's current
            op = operating_point(params, 1, u, v)
            v = ocv - 0.02 * (ocv / 4.2) * op.battery_current_a
        gain = 1.0 + 0.01 * rng.standard_normal()
        thrust = op.thrust_n * gain + 0.02 * rng.standard_normal()
        thrust = thrust * (1.0 + 0.005 * rng.standard_normal(len(u)))
        ok = np.isfinite(thrust) & (op.thrust_n > 0.05)
        n = int(ok.sum())
        ds = Dataset(
            path=f"sim-xnova-s{seed}-{label.replace(' ', '')}.csv",
            format="sim",
            throttle_scale=PWM,
            throttle_native=1000.0 + 1000.0 * u[ok],
            thrust_n=thrust[ok],
            voltage_v=v[ok],
            line=np.arange(2, n + 2, dtype=np.int64),
            meta={"layout": STEP_SUMMARY},
        )
        yield Recording("sim xNova 1 V ESC drop", f"s{seed}", ds, seed not in TUNE_SEEDS, label)


def sim_crazyflie(seeds: tuple[int, ...], tmp: Path) -> Iterator[Recording]:
    """Simulated Crazyflie staircases, 1 s stairs on a creeping load cell (one rotor)."""
    from thrustmap.fitting.loaders.load import load_dataset
    from thrustmap.rig.sim.physics import LoadCellCreep
    from thrustmap.rig.sim.sysid import StaircaseSpec, simulate_staircase, write_csv

    for s in seeds:
        log = simulate_staircase(
            StaircaseSpec(seed=s, levels=8, dwell_s=1.0, cell_update_s=0.1, creep=LoadCellCreep())
        )
        ds = load_dataset(write_csv(log, tmp / f"cf-creep-{s}.csv"))
        aside = s not in TUNE_SEEDS
        yield Recording("sim Crazyflie creep", "cf-aside" if aside else "cf", ds, aside, "1S")


#: public rigs, by manifest name (benchmarks/public-data.toml; THRUSTMAP_PUBLIC_DATA). The
#: diegosdantonio RCbenchmark tests were set aside in wave 5 and missed; they are DEVELOPMENT
#: data since (the top-of-curve rule was built on them). Their rotors follow the author's
#: main.py: EMAX RS1108 with a 2-inch propeller on 2S is 154840 and 214944, on 3S 220513 (and
#: the 3S runs beside it, 220231 and 220340); the three runs of 2020-06-16 21:2x agree with
#: each other (a rotor of their own); every other file is its own rotor.
DIEGO_RS1108 = {"154840": "2S", "214944": "2S", "220231": "3S", "220340": "3S", "220513": "3S"}
DIEGO_EVENING = ("212137", "212732", "213055")
#: rigs set aside in wave 6 before any result on them was looked at (one rotor each, an
#: assumption written in the manifest): (rig, manifest-name prefix)
ASIDE_PUBLIC = (
    ("public 4S 6x3 (jvanderploeg)", "jvanderploeg/"),
    ("public 6S DShot SO_V5 (bhabas)", "bhabas/so-v5/"),
    ("public 4S DShot Impulse Micro (bhabas)", "bhabas/impulse-micro/"),
    ("public 6S ducted fan (avdc)", "avdc/"),
)


def _load_public(name: str, folder: Path | None) -> Dataset | None:
    try:
        (ds,) = load_datasets([str(pd.resolve(name, folder))])
    except (ThrustmapError, pd.PublicDataError):
        return None
    return ds


def public(folder: Path | None) -> Iterator[Recording]:
    """The public rigs of the manifest (files that do not load are skipped, and counted by
    ``Table.failed`` only when a fit fails)."""
    for name in pd.names(source="diegosdantonio"):
        ds = _load_public(name, folder)
        if ds is None or len(ds) < 13:
            continue
        stamp = name.rsplit("_", 1)[-1]
        if stamp in DIEGO_RS1108:
            yield Recording("public RCbenchmark (dev)", "rs1108", ds, False, DIEGO_RS1108[stamp])
        elif stamp in DIEGO_EVENING:
            yield Recording("public RCbenchmark (dev)", "evening", ds, False, "2S")
        else:
            yield Recording("public RCbenchmark (dev)", name, ds, False, "")
    for rig, prefix in ASIDE_PUBLIC:
        for name in pd.names():
            if name.startswith(prefix) and (ds := _load_public(name, folder)) is not None:
                yield Recording(rig, prefix, ds, True, "one pack")


# -- the table ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class BinKey:
    axis: str  # "inside", "thrust", "voltage", "below"
    lo: float
    hi: float

    def label(self) -> str:
        if self.axis == "inside":
            return "inside the region"
        if self.axis == "below":
            return "below the lowest thrust"
        what = "T/reach" if self.axis == "thrust" else "|ln B/Bm|"
        return f"{what} {self.lo:.2f}-{self.hi:.2f}"


def bin_of(ratio: float, rho: float, excess: float, inside: bool) -> BinKey:
    """Beyond the reach: a thrust bin (whatever the voltage); within it, away from the
    voltages measured: a voltage bin; else inside (or below the lowest thrust measured)."""
    if ratio > 1.0 and excess > 0:
        k = int(np.ceil((ratio - 1.0) / THRUST_BIN - 1e-9))
        return BinKey("thrust", 1 + (k - 1) * THRUST_BIN, 1 + k * THRUST_BIN)
    if rho > 1e-9:
        k = int(np.ceil(rho / VOLTAGE_BIN - 1e-9))
        return BinKey("voltage", (k - 1) * VOLTAGE_BIN, k * VOLTAGE_BIN)
    if inside or excess <= 0:
        return BinKey("inside", 0.0, 1.0)
    return BinKey("below", 0.0, 0.0)


def keys_of(s: Scored) -> list[BinKey]:
    return [
        bin_of(float(r), float(p), float(e), bool(i))
        for r, p, e, i in zip(s.ratio, s.rho, s.excess, s.inside, strict=True)
    ]


def within_limit(k: BinKey) -> bool:
    if k.axis == "thrust":
        return k.hi <= EVIDENCE_LIMIT_THRUST_RATIO + 1e-9
    if k.axis == "voltage":
        return k.hi <= EVIDENCE_LIMIT_VOLTAGE_LOG + 1e-9
    return True


@dataclass
class Cell:
    err: list[float] = field(default_factory=list)
    ours: list[bool] = field(default_factory=list)
    main: list[bool] = field(default_factory=list)

    def add(self, err: float, ours: bool, main: bool) -> None:
        self.err.append(err)
        self.ours.append(ours)
        self.main.append(main)

    @property
    def coverage(self) -> float:
        return 100.0 * float(np.mean(self.ours))

    @property
    def coverage_main(self) -> float:
        return 100.0 * float(np.mean(self.main))


def cells(
    runs: list[Scored],
    growth: float,
    factor: float = RECORDING_FACTOR,
    kappa: float = VOLTAGE_EXTRAPOLATION_PCT,
) -> dict[BinKey, Cell]:
    out: dict[BinKey, Cell] = {}
    for s in runs:
        ours = s.err <= s.half(growth, factor, kappa)
        main = s.err <= s.half(None)
        for k, e, o, m in zip(keys_of(s), s.err, ours, main, strict=True):
            out.setdefault(k, Cell()).add(float(e), bool(o), bool(m))
    return out


ORDER = {"inside": 0, "below": 1, "thrust": 2, "voltage": 3}


def print_rig(name: str, runs: list[Scored], growth: float) -> bool:
    """The rig's rows; True when every bin within the limit with evidence meets the goal."""
    met = True
    table = cells(runs, growth)
    kinds = ", ".join(sorted({s.kind for s in runs}))
    print(f"{name} ({len(runs)} maps scored: {kinds})")
    for k in sorted(table, key=lambda k: (ORDER[k.axis], k.lo)):
        c = table[k]
        n = len(c.err)
        flag = ""
        if not within_limit(k):
            flag = "  (beyond the limit: predict refuses)"
        elif n >= MIN_BIN_POINTS and c.coverage < COVERAGE_GOAL_PCT:
            flag = "  BELOW GOAL"
            met = False
        elif n < MIN_BIN_POINTS:
            flag = "  (too few points to be evidence)"
        print(
            f"  {k.label():<24} {n:>5} {np.median(c.err):>8.2f} {c.coverage:>7.1f} "
            f"{c.coverage_main:>9.1f}{flag}"
        )
    return met


def _holds(
    runs: list[Scored], values: tuple[float, float, float], which: Callable[[BinKey], bool]
) -> bool:
    """Every rig's bins chosen by ``which``, within the limit and with evidence, meet the goal
    with (growth, factor, κ) = ``values``."""
    for rig in {s.rig for s in runs}:
        table = cells([s for s in runs if s.rig == rig], *values)
        for k, c in table.items():
            evidence = which(k) and within_limit(k) and len(c.err) >= MIN_BIN_POINTS
            if evidence and c.coverage < COVERAGE_GOAL_PCT:
                return False
    return True


def calibrate(runs: list[Scored]) -> tuple[float, float, float]:
    """In turn, each the smallest holding the goal in every tuning rig's bins: the
    second-recording factor (inside the region and within 10 % of the voltages measured:
    steps of 0.05), κ (the voltage bins beyond: steps of 0.5) and the growth (the thrust
    bins within the limit: steps of 0.25). NaN: none does."""

    def first(grid: np.ndarray, ok: Callable[[float], bool]) -> float:
        return next((float(x) for x in grid if ok(float(x))), float("nan"))

    def near(k: BinKey) -> bool:
        return k.axis == "inside" or (k.axis == "voltage" and k.hi <= VOLTAGE_BIN + 1e-9)

    def far(k: BinKey) -> bool:
        return k.axis == "voltage" and k.lo >= VOLTAGE_BIN - 1e-9

    k0 = VOLTAGE_EXTRAPOLATION_PCT
    factor = first(np.arange(1.0, 4.0, 0.05), lambda f: _holds(runs, (0.0, f, k0), near))
    kappa = first(np.arange(k0, 60.0, 0.5), lambda k: _holds(runs, (0.0, factor, k), far))
    growth = first(
        np.arange(0.0, 40.0, 0.25),
        lambda g: _holds(runs, (g, factor, kappa), lambda k: k.axis == "thrust"),
    )
    return factor, kappa, growth


def evidence_rows(runs: list[Scored], growth: float, rigs: str) -> list[str]:
    table = cells(runs, growth)
    rows = []
    for k in sorted(table, key=lambda k: (ORDER[k.axis], k.lo)):
        if k.axis not in ("thrust", "voltage") or len(table[k].err) < MIN_BIN_POINTS:
            continue
        if not within_limit(k):
            continue
        c = table[k]
        rows.append(
            f'    Bin("{rigs}", "{k.axis}", {k.lo:.2f}, {k.hi:.2f}, {len(c.err)}, '
            f"{np.median(c.err):.2f}, {c.coverage:.1f}, {c.coverage_main:.1f}),"
        )
    return rows


def collect(args: argparse.Namespace, tmp: Path) -> Table:
    table = Table()
    rigs: dict[str, list[Recording]] = {}
    sources = [xnova(args.data), strawson(args.data)]
    sources += [sim_xnova(s) for s in (*TUNE_SEEDS, *ASIDE_SEEDS)]
    sources.append(sim_crazyflie((*TUNE_SEEDS, *ASIDE_SEEDS), tmp))
    if args.public is not None or pd.public_data_dir() is not None:
        sources.append(public(args.public))
    for src in sources:
        for rec in src:
            rigs.setdefault(f"{rec.rig}/{rec.rotor}", []).append(rec)
    for recs in rigs.values():
        experiments(recs, table)
    return table


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=SHARED, help="the shared data folder")
    ap.add_argument(
        "--public",
        type=Path,
        help="the public-data folder of benchmarks/public-data.toml (default: "
        "THRUSTMAP_PUBLIC_DATA, else ../shared/data/public); without it the public rigs are left out",
    )
    ap.add_argument("--calibrate", action="store_true", help="fit the growth on the tuning rigs")
    ap.add_argument("--table", action="store_true", help="print EVIDENCE rows")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    with tempfile.TemporaryDirectory() as tmp:
        table = collect(args, Path(tmp))
    tune = [s for s in table.scored if not s.aside]
    aside = [s for s in table.scored if s.aside]
    growth = EXTRAPOLATION_GROWTH
    if args.calibrate:
        factor, kappa, fitted = calibrate(tune)
        print(
            f"calibration on the tuning rigs (>= {COVERAGE_GOAL_PCT:g} % in every rig's bins): "
            f"second-recording factor {factor:g} (the product uses {RECORDING_FACTOR:g}); "
            f"kappa {kappa:g} (uses {VOLTAGE_EXTRAPOLATION_PCT:g}); growth {fitted:g} up to "
            f"{EVIDENCE_LIMIT_THRUST_RATIO:g}x the reach (uses {EXTRAPOLATION_GROWTH:g})"
        )
    print(
        f"held-out points by distance outside the map's supported region (thrust bins "
        f"{THRUST_BIN:g} of T/reach at B; voltage bins {VOLTAGE_BIN:g} of |ln(B/B_measured)|; "
        f"limit {EVIDENCE_LIMIT_THRUST_RATIO:g}x the reach, |ln B/Bm| "
        f"{EVIDENCE_LIMIT_VOLTAGE_LOG:g}); growth {growth:g} per √reach; main cov: main "
        f"19a0a12's interval (its per-map growth per thrust span, κ {MAIN_KAPPA_PCT:g}, no "
        f"second-recording term); {table.failed} fits failed or had too few points"
    )
    print(f"  {'bin':<24} {'n':>5} {'med err':>8} {'cover':>7} {'main cov':>9}")
    verdicts = []
    for title, runs in (("tuning rigs", tune), ("set-aside rigs", aside)):
        print(f"== {title.upper()} ==")
        failed = [
            rig
            for rig in dict.fromkeys(s.rig for s in runs)
            if not print_rig(rig, [s for s in runs if s.rig == rig], growth)
        ]
        if runs:
            print_rig(f"all {title}", runs, growth)
        verdicts.append(f"{title}: " + (f"NOT met ({', '.join(failed)})" if failed else "met"))
    print(
        f"goal (>= {COVERAGE_GOAL_PCT:g} % in every bin within the limit with >= "
        f"{MIN_BIN_POINTS} points, every rig): {'; '.join(verdicts)}"
    )
    if args.table:
        print("EVIDENCE = (")
        print("\n".join(evidence_rows(tune, growth, "tuning rigs")))
        print("\n".join(evidence_rows(aside, growth, "set-aside rigs")))
        print(")")
    return 0


if __name__ == "__main__":
    sys.exit(main())
