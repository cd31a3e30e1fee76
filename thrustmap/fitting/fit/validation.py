"""Held-out validation: ``validate`` (in-sample, by file, k-fold; the headline counts every
held-out point), ``compare`` over several models, ``evaluate`` of a map on new files."""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from thrustmap.core.errors import ConfigError, FitError, ThrustmapError
from thrustmap.fitting.dataset import Dataset, FloatArray
from thrustmap.fitting.fit.coefficients import (
    NO_POINT_LEFT,
    Pool,
    check_fit_data,
    fit_coefficients,
    pool,
)
from thrustmap.fitting.fit.fitmap import FittedPoints, model_interval, systematic_terms
from thrustmap.fitting.interval import Region
from thrustmap.fitting.mapfile import ThrustMap
from thrustmap.fitting.metrics import Coverage, ErrorStats, coverage, error_stats
from thrustmap.fitting.models import Model, get_model
from thrustmap.fitting.names import VALIDATIONS, Loss, Validation
from thrustmap.fitting.selection.options import Selection
from thrustmap.fitting.selection.points import select
from thrustmap.fitting.solve import solve_gram

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Row:
    """Held-out errors of one model: ALL held-out points (the headline), and the same points
    split into inside and outside the training points' supported region (detail)."""

    model: str
    validation: str
    inside: ErrorStats  # held-out points inside the training points' supported region
    outside: ErrorStats  # held-out points outside it
    folds: int
    all: ErrorStats  # every held-out point: the headline
    #: why the model could not be fitted under this validation ("" when it was: a model that
    #: cannot be fitted gets a row saying why, and the other models keep theirs)
    error: str = ""
    #: how many held-out points the map's 95 % interval held, inside / outside the supported
    #: region (None: the map has no interval, or it could not be learned on the fold)
    coverage_inside: Coverage | None = None
    coverage_outside: Coverage | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (no NaN: a figure with no points is null). Top-level figures are over all
        held-out points; ``inside_supported_region`` and ``outside_supported_region`` give the
        split (``inside_box``/``outside_box``, their names before, are kept as aliases)."""
        d: dict[str, Any] = {
            "model": self.model,
            "validation": self.validation,
            "folds": self.folds,
        }
        if self.error:
            d["error"] = self.error
        d.update(self.all.to_dict())
        d["inside_supported_region"] = self.inside.to_dict()
        d["outside_supported_region"] = self.outside.to_dict()
        d["inside_box"] = d["inside_supported_region"]  # the names before: kept for old readers
        d["outside_box"] = d["outside_supported_region"]
        if self.coverage_inside is not None and self.coverage_outside is not None:
            cells = {
                "inside_supported_region": self.coverage_inside.to_dict(),
                "outside_supported_region": self.coverage_outside.to_dict(),
            }
            d["coverage_pct"] = {k: v["coverage_pct"] for k, v in cells.items()}
            d["interval_median_half_width_pct"] = {
                k: v["median_half_width_pct"] for k, v in cells.items()
            }
        return d


def _row(
    model: str,
    validation: str,
    folds: int,
    pred: FloatArray,
    true: FloatArray,
    inside: np.ndarray[Any, np.dtype[np.bool_]],
    half_width: FloatArray | None = None,
) -> Row:
    """``half_width``: the map's interval at each point (NaN where a fold had none)."""
    cov_in = cov_out = None
    if half_width is not None:
        has = np.isfinite(half_width)
        cov_in = coverage(pred[inside & has], true[inside & has], half_width[inside & has])
        cov_out = coverage(pred[~inside & has], true[~inside & has], half_width[~inside & has])
    return Row(
        model=model,
        validation=validation,
        inside=error_stats(pred[inside], true[inside]),
        outside=error_stats(pred[~inside], true[~inside]),
        folds=folds,
        all=error_stats(pred, true),
        coverage_inside=cov_in,
        coverage_outside=cov_out,
    )


def _in_box(
    t: FloatArray, b: FloatArray, t_tr: FloatArray, b_tr: FloatArray, uses_voltage: bool
) -> Any:
    """Inside the training points' supported region (their thrust range for a model that
    ignores voltage)."""
    if uses_voltage:
        return Region.from_points(t_tr, b_tr).contains(t, b)
    return (t >= t_tr.min()) & (t <= t_tr.max())


def _conditioned_bounds(
    m: Model, to_raw: Callable[[FloatArray], FloatArray]
) -> tuple[FloatArray | None, FloatArray | None]:
    """The model's bounds in its conditioned basis. A bounded model's conditioning is a column
    scaling (raw = conditioned × s), so each bound divides by its column's s."""
    lower, upper = m.lower(), m.upper()
    if lower is None and upper is None:
        return None, None
    scale = to_raw(np.ones(m.n_coefficients))
    with np.errstate(invalid="ignore"):
        lo = None if lower is None else np.where(np.isfinite(lower), lower / scale, lower)
        hi = None if upper is None else np.where(np.isfinite(upper), upper / scale, upper)
    return lo, hi


def validate(
    data: Pool,
    model: str,
    validation: Validation,
    loss: Loss = "l2",
    folds: int = 5,
    seed: int = 0,
    with_coverage: bool = True,
) -> Row:
    """Held-out errors of ``model`` under ``validation``; with ``with_coverage`` each fold's
    map also learns its 95 % interval (as ``fit`` would) and the row says how many held-out
    points it held."""
    m = get_model(model)
    n = len(data)
    if validation == "in-sample":
        splits = [(np.ones(n, bool), np.ones(n, bool))]
    elif validation == "by-file":
        k = len(data.points)
        if k < 2:
            raise ConfigError("by-file validation needs at least two files")
        splits = [(data.file_index != i, data.file_index == i) for i in range(k)]
    elif validation == "kfold":
        if n < folds:
            raise ConfigError(f"kfold needs at least {folds} points, have {n}")
        fold = np.random.default_rng(seed).permutation(n) % folds
        splits = [(fold != i, fold == i) for i in range(folds)]
    else:
        raise ConfigError(
            f"unknown validation '{validation}'; expected one of: {', '.join(VALIDATIONS)}"
        )
    preds: list[FloatArray] = []
    trues: list[FloatArray] = []
    insides: list[np.ndarray[Any, np.dtype[np.bool_]]] = []
    halves: list[FloatArray] = []
    fast = loss == "l2" and m.linear_least_squares
    weighted = m.fit_weights(data.throttle_pct[:0]) is not None
    if fast:
        # One conditioned design for all points; each fold's fit comes from sums of per-split
        # normal equations, so k folds cost one pass over the samples, not k (a model that
        # weighs its points by the range they cover weighs each fold's own points: one
        # weighted product per fold).
        design, to_raw = m.conditioned(data.thrust_n, data.voltage_v)
        lower_c, upper_c = _conditioned_bounds(m, to_raw)
        if not weighted:
            gram_all = design.T @ design
            rhs_all = design.T @ data.throttle_pct
    for train, test in splits:
        t, b, th = data.take(train)
        tt, bt, tht = data.take(test)
        if fast:
            check_fit_data(m, t, b, f"{model} {validation} fold", th)
            dt = design[test]
            if weighted:
                w = np.zeros(n)
                w[train] = m.fit_weights(th, data.file_index[train])
                wd = design * w[:, None]
                gram, rhs = wd.T @ design, wd.T @ data.throttle_pct
            elif validation == "in-sample":
                gram, rhs = gram_all, rhs_all
            else:
                gram, rhs = gram_all - dt.T @ dt, rhs_all - dt.T @ tht
            cols = m.free_columns(t, b)
            coef_c = np.zeros(m.n_coefficients)
            coef_c[cols] = solve_gram(
                gram[np.ix_(cols, cols)],
                rhs[cols],
                None if lower_c is None else lower_c[cols],
                None if upper_c is None else upper_c[cols],
            )
            pred = dt @ coef_c
            coef = to_raw(coef_c)
        else:
            coef = fit_coefficients(
                m, t, b, th, loss, f"{model} {validation} fold", data.file_index[train]
            )
            pred = m.evaluate(coef, tt, bt)
        halves.append(
            _fold_half_width(m, coef, data, train, tt, bt, loss)
            if with_coverage and validation != "in-sample"
            else np.full(len(tt), np.nan)
        )
        inside = (
            _in_box(tt, bt, t, b, m.uses_voltage)
            if validation != "in-sample"
            else np.ones(len(tt), bool)
        )
        preds.append(pred)
        trues.append(tht)
        insides.append(np.asarray(inside, bool))
    return _row(
        model,
        validation,
        len(splits),
        np.concatenate(preds),
        np.concatenate(trues),
        np.concatenate(insides),
        np.concatenate(halves) if with_coverage and validation != "in-sample" else None,
    )


def _fold_half_width(
    m: Model,
    coef: FloatArray,
    data: Pool,
    train: np.ndarray[Any, np.dtype[np.bool_]],
    tt: FloatArray,
    bt: FloatArray,
    loss: Loss,
) -> FloatArray:
    """The fold's map's 95 % interval at the held-out points (NaN: none could be learned)."""
    t, b, th = data.take(train)
    files = sorted({int(f) for f in np.unique(data.file_index[train])})
    try:
        iv = model_interval(
            m,
            coef,
            FittedPoints(t, b, th, data.file_index[train]),
            loss,
            systematic=systematic_terms([data.points[f] for f in files]),
        )
    except (ThrustmapError, np.linalg.LinAlgError, ValueError):
        iv = None
    if iv is None:
        return np.full(len(tt), np.nan)
    return np.asarray(iv.half_width(tt, bt, m.design(tt, bt)), dtype=float)


def compare(
    datasets: Sequence[Dataset],
    models: Sequence[str],
    validation: Validation,
    *,
    loss: Loss = "l2",
    selection: Selection | None = None,
    folds: int = 5,
    with_coverage: bool = True,
) -> list[Row]:
    data = pool(datasets, selection or Selection())
    for name in models:
        get_model(name)  # an unknown name is refused before anything is fitted
    if not len(data.thrust_n):  # (no design to condition: every model would fail alike)
        raise FitError(NO_POINT_LEFT, file=", ".join(str(d.path) for d in datasets))
    rows = []
    for name in models:
        try:
            rows.append(validate(data, name, validation, loss, folds, with_coverage=with_coverage))
        except FitError as exc:  # this model only: the others keep their rows
            log.info("%s: %s", name, exc)
            empty = error_stats(np.zeros(0), np.zeros(0))
            rows.append(Row(name, validation, empty, empty, 0, empty, error=str(exc)))
    if all(r.error for r in rows):
        raise FitError("no model could be fitted: " + "; ".join(r.error for r in rows))
    return rows


def evaluate(
    tmap: ThrustMap, datasets: Sequence[Dataset], selection: Selection | None = None
) -> list[Row]:
    """Score a map on files: every point (the headline), and inside/outside its box apart."""
    rows = []
    for ds in datasets:
        if ds.throttle_scale != tmap.throttle_scale:
            raise ConfigError(
                f"{ds.name} uses throttle scale {ds.throttle_scale.name} {ds.throttle_scale.lo:g}.."
                f"{ds.throttle_scale.hi:g} but the map uses {tmap.throttle_scale.name} "
                f"{tmap.throttle_scale.lo:g}..{tmap.throttle_scale.hi:g}"
            )
        p = select(ds, selection or Selection())
        pred = tmap.throttle_pct(p.thrust_n, p.voltage_v, corrected=False)
        inside = tmap.in_box(p.thrust_n, p.voltage_v)
        half = tmap.interval_pct(p.thrust_n, p.voltage_v, corrected=False)
        rows.append(_row(tmap.model, f"evaluate:{ds.name}", 1, pred, p.throttle_pct, inside, half))
    if datasets and not any(r.all.n for r in rows):  # a score of nothing is no score
        raise FitError(NO_POINT_LEFT, file=", ".join(str(d.path) for d in datasets))
    return rows
