"""Everything a report or a figure shows, computed once from a map and the files it came from.

The numbers come from the same library functions the CLI uses (``compare`` for the validation
table, the map's γ block as ``gamma fit`` wrote it, ``export_map`` for firmware parameters), so
a report and the CLI can never disagree.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from thrustmap.core.errors import ConfigError, ThrustmapError
from thrustmap.core.version import package_version
from thrustmap.fitting.dataset import Dataset
from thrustmap.fitting.fit.coefficients import Pool, pool
from thrustmap.fitting.fit.fitmap import top_warnings
from thrustmap.fitting.fit.validation import Row, validate
from thrustmap.fitting.mapfile import ThrustMap, file_sha256
from thrustmap.fitting.mapvalues import MapValues, map_values
from thrustmap.fitting.names import DEFAULT_MODEL, Loss
from thrustmap.fitting.selection.options import (
    ROLE_PLATEAU,
    ROLE_SETTLING,
    ROLE_STAIR_PAIR,
    Selection,
)
from thrustmap.fitting.selection.points import select

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
#: the models of the validation table: the seed paper's four (Table 3) and the physics model
TABLE_MODELS = ("poly2", "poly2-trunc", "poly3", "poly3-trunc", DEFAULT_MODEL)
GRID_N = 40


@dataclass
class SweepMask:
    """Per-sample role in steady-state selection, for the raw-sweep figure."""

    kept: npt.NDArray[np.bool_]  # settled plateau samples (averaged into points) or all samples
    settling: npt.NDArray[np.bool_]  # plateau samples dropped while the rotor settled
    other: npt.NDArray[np.bool_]  # ramps and transitions (ramp pairs are used per the report)
    # stairs of a quasi-static staircase, paired up/down at equal command
    stair_pair: npt.NDArray[np.bool_] | None = None


@dataclass
class GammaData:
    """The map's γ block and, when its Df files are found, the per-sample γ_j = T_c/F_m."""

    coefficients: tuple[float, ...]
    voltage_v: tuple[float, float]
    loss: str
    metrics: dict[str, Any]
    sources: list[dict[str, Any]]
    sample_voltage_v: FloatArray | None = None
    sample_gamma: FloatArray | None = None
    note: str = ""


@dataclass
class ExportRow:
    target: str
    values: dict[str, str]
    residual: dict[str, float]
    note: str = ""


@dataclass
class ReportData:
    map_path: str
    tmap: ThrustMap
    datasets: list[Dataset]
    sidecars: list[dict[str, Any]]
    selection: Selection
    points: Pool
    residual_pct: FloatArray  # map prediction − measured throttle, per selected point
    masks: list[SweepMask]
    validation: dict[str, list[Row]]
    grid_t: FloatArray
    grid_b: FloatArray
    grid_th: FloatArray
    grid_pi_pct: FloatArray  # 95 % prediction-interval half-width, % throttle
    grid_count: npt.NDArray[np.int64]  # selected points per grid cell
    suggestion: tuple[float, float] | None
    gamma: GammaData | None
    exports: list[ExportRow]
    notes: list[str] = field(default_factory=list)
    tool_version: str = field(default_factory=package_version)
    #: the map's values every export writes (``fitting.mapvalues``), None: not computed
    map_values: MapValues | None = None
    #: the stand logs given that are not the map's sources (by sha256): scored, not fitted on
    foreign: list[str] = field(default_factory=list)

    @property
    def map_label(self) -> str:
        """What to call the map in titles and tables: its strategy (SR, MR, LA) when recorded,
        else its file name, never "unknown"."""
        if self.tmap.strategy and self.tmap.strategy != "unknown":
            return f"{self.tmap.strategy} map"
        return Path(self.map_path).name


# -- finding the data ----------------------------------------------------------------------------


def resolve_sources(tmap: ThrustMap, map_path: str | Path) -> list[str]:
    """The stand logs a map was fitted from, as recorded in it: the path as written, else the
    same name next to the map. One clear error when they are not where the map says."""
    if not tmap.sources:
        raise ConfigError(
            f"{map_path}: the map records no source files; give the stand logs after the map"
        )
    here = Path(map_path).resolve().parent
    found: list[str] = []
    for src in tmap.sources:
        raw = str(src.get("path", ""))
        candidates = [Path(raw), here / raw, here / Path(raw).name]
        hit = next((c for c in candidates if raw and c.is_file()), None)
        if hit is None:
            raise ConfigError(
                f"{map_path}: source '{raw}' is not where the map recorded it (moved?); "
                "give the stand logs after the map: thrustmap report MAP FILE..."
            )
        _same_as_fitted(hit, src.get("sha256"), map_path)
        found.append(str(hit))
    return found


def _same_as_fitted(path: Path, recorded: Any, map_path: str | Path) -> None:
    """Refuse a recorded source whose content is no longer what the map was fitted on (its
    sha256 differs from the one the map records): read as the map's data, it would be another
    recording shown as the fit's, or a file no longer a stand log at all."""
    if not isinstance(recorded, str) or not recorded:
        return  # an older map without hashes: not checkable (said by not_its_sources)
    if file_sha256(path) != recorded:
        raise ConfigError(
            f"{map_path}: source '{path}' changed since the fit: its content differs from "
            f"what the map was fitted on (sha256 {recorded[:12]}... recorded); restore it, "
            "refit, or give the stand logs after the map to show them as new data"
        )


def _sidecar(path: str) -> dict[str, Any]:
    """A thrustmap Ds log's JSON sidecar (devices, plan), or {} for other formats."""
    from thrustmap.core.jsonfile import load_json

    p = Path(path)
    side = p.with_name(p.stem + ".meta.json")
    if not side.is_file():
        return {}
    try:
        data = load_json(side, what="Ds sidecar")
    except ThrustmapError as exc:
        log.warning("%s", exc)
        return {}
    return data if isinstance(data, dict) else {}


def selection_of(tmap: ThrustMap) -> Selection:
    """The selection the map was fitted with (ranges and method as recorded)."""
    s = tmap.selection

    def rng(key: str) -> tuple[float, float] | None:
        v = s.get(key)
        return None if v is None else (float(v[0]), float(v[1]))

    kw: dict[str, Any] = {
        "throttle_range": rng("throttle_range"),
        "voltage_range": rng("voltage_range"),
        "thrust_range": rng("thrust_range"),
        "all_samples": bool(s.get("all_samples", False)),
    }
    for key in (
        "plateau_tolerance_pct",
        "settle_sigmas",
        "lag_budget_pct",
        "trend_rel",
        "stall_fraction",
        "quasi_static_updates",
        "quasi_static_lags",
        "pair_voltage_rel",
    ):
        if isinstance(s.get(key), int | float) and not isinstance(s.get(key), bool):
            kw[key] = float(s[key])
    for flag in ("drop_tare_points", "keep_past_top"):
        if isinstance(s.get(flag), bool):
            kw[flag] = s[flag]
    return Selection(**kw)


def sweep_mask(ds: Dataset, sel: Selection) -> SweepMask:
    """Which samples steady-state selection averaged, which it dropped while settling, and
    which it paired on the legs of a quasi-static staircase: the selection's own record."""
    n = len(ds)
    kept = np.zeros(n, bool)
    settling = np.zeros(n, bool)
    if sel.all_samples:
        return SweepMask(np.ones(n, bool), settling, np.zeros(n, bool))
    try:
        roles = select(ds, sel).roles
    except ThrustmapError:  # nothing steady in this file: every sample is "other"
        roles = None
    if roles is None:
        return SweepMask(kept, settling, ~kept)
    kept = roles == ROLE_PLATEAU
    settling = roles == ROLE_SETTLING
    paired = roles == ROLE_STAIR_PAIR
    return SweepMask(kept, settling, ~(kept | settling | paired), paired)


# -- uncertainty ---------------------------------------------------------------------------------


def prediction_interval(tmap: ThrustMap, t: FloatArray, b: FloatArray) -> FloatArray:
    """The map's own 95 % prediction-interval half-width (% throttle) at (t, b): the interval
    fit, predict and the map file give (held-out residuals and the coefficients' uncertainty,
    widening outside the supported region). NaN everywhere for a map without one."""
    half = tmap.interval_pct(t, b, corrected=False)
    if half is None:
        return np.full(np.shape(t), np.nan)
    return np.asarray(half, dtype=float)


def where_to_test(
    tmap: ThrustMap, t: FloatArray, b: FloatArray, th: FloatArray, pi: FloatArray
) -> tuple[float, float] | None:
    """The grid point with the widest interval among those the motor can reach (the map's
    throttle within 0..100 % of the scale there); None when no such point has an interval."""
    ok = np.isfinite(pi) & np.isfinite(th) & (th >= 0.0) & (th <= 100.0)
    if not ok.any():
        return None
    masked = np.where(ok, pi, -np.inf)
    i, j = np.unravel_index(int(np.argmax(masked)), masked.shape)
    return float(t[i, j]), float(b[i, j])


# -- γ ------------------------------------------------------------------------------------------


def _gamma_data(tmap: ThrustMap, map_path: str) -> GammaData | None:
    c = tmap.correction
    if c is None:
        return None
    g = GammaData(
        coefficients=c.coefficients,
        voltage_v=(c.voltage_v.lo, c.voltage_v.hi),
        loss=c.loss,
        metrics=dict(c.metrics),
        sources=[dict(s) for s in c.sources],
    )
    here = Path(map_path).resolve().parent
    paths = []
    for src in g.sources:
        raw = str(src.get("path", ""))
        hit = next((p for p in (Path(raw), here / raw, here / Path(raw).name) if p.is_file()), None)
        if hit is None:
            g.note = f"Df '{raw}' not found where the map recorded it: γ data points not shown"
            return g
        paths.append(hit)
    if not paths:
        g.note = "the γ block records no Df files: γ data points not shown"
        return g
    try:
        import pandas as pd

        from thrustmap.fitting.df.dffile import read_df
        from thrustmap.fitting.gamma import thrust_command_n

        tables = []
        side: dict[str, Any] = {}
        for p in paths:
            table, s = read_df(p)
            tables.append(table)
            for k in ("columns", "flights"):
                side.setdefault(k, {}).update(s.get(k, {}))
        table = pd.concat(tables, ignore_index=True)
        t_cmd, _ = thrust_command_n(table, side, tmap.with_correction(None))
        force = table["force_n"].to_numpy(float)
        volt = table["voltage_v"].to_numpy(float)
        ok = np.isfinite(t_cmd) & np.isfinite(force) & np.isfinite(volt) & (force > 0) & (t_cmd > 0)
        g.sample_voltage_v = volt[ok]
        g.sample_gamma = t_cmd[ok] / force[ok]
    except ThrustmapError as exc:
        g.note = f"γ data points not shown: {exc}"
    return g


# -- exports -------------------------------------------------------------------------------------


def _exports(tmap: ThrustMap, betaflight_firmware: str | None) -> list[ExportRow]:
    """Each firmware target with ``thrustmap export``'s defaults. Betaflight's thrust_linear
    changed formula in 2026.6: the FC's recorded firmware is used, else both generations."""
    from thrustmap.fitting.export.encodings import ExportOptions
    from thrustmap.fitting.export.targets import export_map

    jobs: list[tuple[str, str, ExportOptions]] = [
        ("px4", "px4", ExportOptions()),
        ("ardupilot", "ardupilot", ExportOptions()),
    ]
    if betaflight_firmware:
        jobs.append(
            (
                f"betaflight {betaflight_firmware} (the FC's)",
                "betaflight",
                ExportOptions(firmware=betaflight_firmware),
            )
        )
    else:
        for fw in ("4.5", "2026.6"):
            jobs.append((f"betaflight {fw} (assumed)", "betaflight", ExportOptions(firmware=fw)))
    jobs.append(("aerostack2", "aerostack2", ExportOptions()))
    rows = []
    for label, target, opts in jobs:
        try:
            res = export_map(tmap, target, opts)
        except ThrustmapError as exc:
            rows.append(ExportRow(label, {}, {}, note=str(exc)))
            continue
        values = {
            k: (f"{v:.6g}" if isinstance(v, float) else str(v))
            for k, v in res.values.items()
            if isinstance(v, (int, float, str))
        }
        rows.append(ExportRow(label, values, dict(res.residual)))
    return rows


def _betaflight_firmware(sidecars: list[dict[str, Any]]) -> str | None:
    for side in sidecars:
        fc = (side.get("devices") or {}).get("throttle_output") or {}
        if isinstance(fc, dict) and fc.get("kind") == "betaflight" and fc.get("firmware_version"):
            return str(fc["firmware_version"])
    return None


# -- all of it ----------------------------------------------------------------------------------


def build(
    map_path: str | Path,
    data_paths: list[str] | None = None,
    *,
    with_exports: bool = True,
    with_validation: bool = True,
) -> ReportData:
    """Load the map and its data and compute every number a report or a figure shows."""
    from thrustmap.fitting.loaders.load import load_datasets

    map_path = str(map_path)
    tmap = ThrustMap.load(map_path)
    paths = list(data_paths) if data_paths else resolve_sources(tmap, map_path)
    datasets = load_datasets(paths)
    notes: list[str] = []
    sel = selection_of(tmap)
    foreign = not_its_sources(tmap, datasets, notes)
    sidecars = [_sidecar(p) for p in paths]
    data = pool(datasets, sel)
    notes.extend(top_warnings(data.points, tmap.saturation))
    pred = tmap.throttle_pct(data.thrust_n, data.voltage_v, corrected=False)
    residual = np.asarray(pred - data.throttle_pct, dtype=float)
    v = tmap.validity
    gt, gb = np.meshgrid(
        np.linspace(v.thrust_n.lo, v.thrust_n.hi, GRID_N),
        np.linspace(v.voltage_v.lo, v.voltage_v.hi, GRID_N),
    )
    gth = tmap.throttle_pct(gt, gb, corrected=False)
    pi = prediction_interval(tmap, gt, gb)
    if not np.isfinite(pi).any():
        notes.append("the map records no prediction interval (fitted by an older thrustmap)")
    count, _, _ = np.histogram2d(
        data.voltage_v,
        data.thrust_n,
        bins=[
            np.linspace(v.voltage_v.lo, v.voltage_v.hi, 9),
            np.linspace(v.thrust_n.lo, v.thrust_n.hi, 9),
        ],
    )
    suggestion = where_to_test(tmap, gt, gb, gth, pi)
    validation: dict[str, list[Row]] = {}
    if with_validation:
        validation = _validations(tmap, datasets, foreign, sel, notes)
    return ReportData(
        map_path=map_path,
        tmap=tmap,
        datasets=datasets,
        sidecars=sidecars,
        selection=sel,
        points=data,
        residual_pct=residual,
        masks=[sweep_mask(d, sel) for d in datasets],
        validation=validation,
        grid_t=gt,
        grid_b=gb,
        grid_th=gth,
        grid_pi_pct=pi,
        grid_count=count.astype(np.int64),
        suggestion=suggestion,
        gamma=_gamma_data(tmap, map_path),
        exports=_exports(tmap, _betaflight_firmware(sidecars)) if with_exports else [],
        map_values=map_values(tmap) if with_exports else None,
        notes=notes,
        foreign=foreign,
    )


def _validations(
    tmap: ThrustMap, datasets: list[Dataset], foreign: list[str], sel: Selection,
    notes: list[str],
) -> dict[str, list[Row]]:  # fmt: skip
    """Every model's validation (in-sample, by-file, k-fold) on the map's own sources, and the
    map's error on each stand log that is not one of them."""
    validation = _foreign_rows(tmap, datasets, foreign, sel, notes) if foreign else {}
    own = [ds for ds in datasets if ds.path not in foreign]
    if not own:
        notes.append(
            "no data given are the map's sources: the validation of its fit (in-sample, "
            "by-file, k-fold) needs them, and was left out"
        )
        return validation
    data = pool(own, sel)
    loss: Loss = "l1" if tmap.loss == "l1" else "l2"  # the map's loss, as fitted
    for mode in ("in-sample", "by-file", "kfold"):
        if mode == "by-file" and len(own) < 2:
            notes.append("by-file validation needs two or more files: column left out")
            continue
        try:
            # compare() is pool() + validate() per model: the pool is selected once here.
            validation[mode] = [validate(data, m, mode, loss) for m in TABLE_MODELS]
        except ThrustmapError as exc:
            notes.append(f"{mode} validation not computed: {exc}")
    return validation


def not_its_sources(tmap: ThrustMap, datasets: list[Dataset], notes: list[str]) -> list[str]:
    """The paths of the stand logs that are not the map's sources: their sha256 is not among
    those the map records (a source whose file changed since the fit is said as such)."""
    shas = {str(s.get("sha256")) for s in tmap.sources if s.get("sha256")}
    by_name = {Path(str(s.get("path", ""))).name: s.get("sha256") for s in tmap.sources}
    if not shas:
        notes.append(
            "the map records no sha256 of its sources: whether these data are the ones it "
            "was fitted on cannot be checked"
        )
        return []
    foreign = []
    for ds in datasets:
        if ds.sha256 in shas:
            continue
        foreign.append(ds.path)
        if by_name.get(ds.name):
            notes.append(
                f"{ds.name}: sha256 differs from the one the map recorded (the file changed "
                "since the fit): taken as data that are not its sources"
            )
    return foreign


def _foreign_rows(
    tmap: ThrustMap, datasets: list[Dataset], foreign: list[str], sel: Selection,
    notes: list[str],
) -> dict[str, list[Row]]:  # fmt: skip
    """The map's own error on each stand log that is not one of its sources (every point;
    inside and outside its supported region beside it), said in a note as well."""
    from thrustmap.fitting.fit.validation import evaluate

    rows: dict[str, list[Row]] = {}
    said = []
    for ds in datasets:
        if ds.path not in foreign:
            continue
        try:
            (row,) = evaluate(tmap, [ds], sel)
        except ThrustmapError as exc:
            said.append(f"{ds.name} (not scored: {exc})")
            continue
        rows[f"the map on {ds.name} (not its source)"] = [row]
        said.append(f"{ds.name}: mean {row.all.mean_pct:.3f} % (n={row.all.n})")
    notes.append(
        f"{len(foreign)} of the {len(datasets)} stand logs are not the map's sources (their "
        "sha256 is not among those it records): they are shown as new data, scored by the "
        "map, never as its fit; the map's error on them (e_Th, every point): " + "; ".join(said)
    )
    return rows


def source_files(rd: ReportData) -> list[dict[str, Any]]:
    """Provenance rows: every input with its sha256 (computed now) and what it says it is."""
    rows: list[dict[str, Any]] = [
        {
            "role": "map",
            "path": rd.map_path,
            "sha256": rd.tmap.file_sha256 or file_sha256(rd.map_path),
        }
    ]
    for ds, side in zip(rd.datasets, rd.sidecars, strict=True):
        devices = side.get("devices", {}) if isinstance(side.get("devices"), dict) else {}
        fc = devices.get("throttle_output", {}) if isinstance(devices, dict) else {}
        stand = devices.get("stand", {}) if isinstance(devices, dict) else {}
        rows.append(
            {
                "role": "stand log" + (" (not the map's source)" if ds.path in rd.foreign else ""),
                "path": ds.path,
                "sha256": ds.sha256 or file_sha256(ds.path),
                "format": ds.format,
                "samples": len(ds),
                "stand": stand.get("kind") or ds.meta.get("stand") or "not recorded",
                "fc": " ".join(
                    str(x)
                    for x in (fc.get("kind"), fc.get("board"), fc.get("firmware_version"))
                    if x
                )
                or "not recorded",
                "motor_protocol": fc.get("motor_protocol") or "not recorded",
                "battery_cells": fc.get("battery_cells") or side.get("cells") or "not recorded",
                "rotors_on_esc": ds.rotors_on_esc or side.get("rotors_on_esc") or "not recorded",
                "throttle_scale": f"{ds.throttle_scale.name} {ds.throttle_scale.lo:g}.."
                f"{ds.throttle_scale.hi:g} {ds.throttle_scale.unit_label}",
            }
        )
    if rd.gamma is not None:
        for s in rd.gamma.sources:
            rows.append(
                {"role": "Df (γ)", "path": s.get("path", ""), "sha256": s.get("sha256", "")}
            )
    return rows
