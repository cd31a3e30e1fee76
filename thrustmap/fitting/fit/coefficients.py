"""The points a fit sees (``pool``: every file's selected points, with their file index),
a model's coefficients from them, and the coefficients' covariance."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from thrustmap.core.errors import ConfigError, FitError
from thrustmap.core.units import ThrottleScale
from thrustmap.fitting.dataset import Dataset, FloatArray, IntArray
from thrustmap.fitting.models import Identification, Model
from thrustmap.fitting.names import Loss
from thrustmap.fitting.selection.options import Selection
from thrustmap.fitting.selection.points import Points, select

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Pool:
    """Selected points of several files, concatenated, with their file index."""

    thrust_n: FloatArray
    voltage_v: FloatArray
    throttle_pct: FloatArray
    file_index: np.ndarray[Any, np.dtype[np.int64]]
    points: tuple[Points, ...]
    scale: ThrottleScale

    def __len__(self) -> int:
        return len(self.thrust_n)

    def take(self, mask: np.ndarray[Any, Any]) -> tuple[FloatArray, FloatArray, FloatArray]:
        return self.thrust_n[mask], self.voltage_v[mask], self.throttle_pct[mask]


def pool(datasets: Sequence[Dataset], selection: Selection) -> Pool:
    if not datasets:
        raise ConfigError("no datasets given")
    scales = {d.throttle_scale for d in datasets}
    if len(scales) > 1:
        listed = ", ".join(
            f"{d.name}: {d.throttle_scale.name} {d.throttle_scale.lo:g}..{d.throttle_scale.hi:g}"
            for d in datasets
        )
        raise ConfigError(f"files use different throttle scales ({listed}); fit them separately")
    pts = tuple(select(d, selection) for d in datasets)
    for p, d in zip(pts, datasets, strict=True):
        log.info("%s: kept %d points (%s)", d.name, len(p), p.report)
    return Pool(
        thrust_n=np.concatenate([p.thrust_n for p in pts]),
        voltage_v=np.concatenate([p.voltage_v for p in pts]),
        throttle_pct=np.concatenate([p.throttle_pct for p in pts]),
        file_index=np.concatenate([np.full(len(p), i, dtype=np.int64) for i, p in enumerate(pts)]),
        points=pts,
        scale=datasets[0].throttle_scale,
    )


#: pooled points spanning less throttle than this (% of the scale) are one level: no map
MIN_THROTTLE_SPAN_PCT = 1.0

#: what is said when selection leaves no point (steady points were found, else that was
#: refused earlier: the range options left none)
NO_POINT_LEFT = (
    "no point is left after selection: do the range options hold the data? "
    "(--throttle-range is in the log's native units, e.g. 1100:1900 µs, not %; "
    "--voltage-range in V, not mV; --thrust-range in N)"
)


def check_fit_data(
    model: Model, t: FloatArray, b: FloatArray, where: str, th: FloatArray | None = None
) -> None:
    """Refuse data that cannot determine ``model``: no point, fewer points than coefficients,
    one voltage for a surface in voltage, one thrust level, one throttle level (``th``, % of
    the scale: thrust that moves while the command does not)."""
    if len(t) == 0:
        raise FitError(NO_POINT_LEFT, file=where)
    if len(t) < model.n_coefficients:
        raise FitError(
            f"{len(t)} points after selection cannot determine the {model.n_coefficients} "
            f"coefficients of '{model.name}'; widen the ranges or record more levels",
            file=where,
        )
    if model.uses_voltage and not model.voltage_from_physics and np.ptp(b) < 0.05:
        raise FitError(
            f"all points at one battery voltage ({np.mean(b):.2f} V): a surface in voltage cannot be "
            f"fitted; record over a discharge, or use a model without voltage (linear, la)",
            file=where,
        )
    if np.ptp(t) <= 0:
        raise FitError("all points at one thrust level; need several throttle levels", file=where)
    if th is not None and float(np.ptp(th)) < MIN_THROTTLE_SPAN_PCT:
        raise FitError(
            f"every point is at one throttle ({float(np.mean(th)):.1f} %): a map needs several "
            "levels (a sweep); is the throttle column the command? (a log held at one level "
            "can be scored with `thrustmap evaluate`, not fitted)",
            file=where,
        )


def fit_coefficients(
    model: Model,
    t: FloatArray,
    b: FloatArray,
    th: FloatArray,
    loss: Loss,
    where: str = "<data>",
    groups: IntArray | None = None,
) -> FloatArray:
    return identify_coefficients(model, t, b, th, loss, where, groups)[0]


def identify_coefficients(
    model: Model,
    t: FloatArray,
    b: FloatArray,
    th: FloatArray,
    loss: Loss,
    where: str = "<data>",
    groups: IntArray | None = None,
) -> tuple[FloatArray, Identification | None]:
    """Coefficients and how they were identified (which were set by physics, and why);
    ``groups``: each point's file (a model that weighs its points weighs each file's own)."""
    check_fit_data(model, t, b, where, th)
    coef, ident = model.identify(t, b, th, loss, groups)
    if not np.all(np.isfinite(coef)):
        raise FitError(
            f"fit of '{model.name}' gave non-finite coefficients; the data cannot determine "
            "this model (record more levels or use a simpler model)",
            file=where,
        )
    return coef, ident


def parameter_covariance(
    model: Model,
    coef: FloatArray,
    t: FloatArray,
    b: FloatArray,
    th: FloatArray,
    ident: Identification | None,
    groups: IntArray | None = None,
) -> FloatArray | None:
    """Covariance of the raw coefficients (least-squares, linearised at the fit): residual
    variance × (XᵀX)⁻¹ over the coefficients the data determined; a coefficient held by
    physics or resting on its bound contributes nothing. A model that weighs its points
    (``Model.fit_weights``) gets the sandwich form (XᵀWX)⁻¹ XᵀW diag(e²) WX (XᵀWX)⁻¹, scaled by
    n / dof: its weights say how much of the range a point stands for, not how noisy it is.
    None when it cannot be computed."""
    if len(t) <= 1:
        return None
    design, to_raw = model.conditioned(t, b)
    k = model.n_coefficients
    free = np.ones(k, bool)
    if ident is not None and ident.fixed:
        names = list(model.term_names)
        for name in ident.fixed:
            if name in names:
                free[names.index(name)] = False
    lower = model.lower()
    upper = model.upper()
    for i in range(k):
        if (
            lower is not None
            and np.isfinite(lower[i])
            and abs(coef[i] - lower[i]) <= 1e-9 * (1.0 + abs(lower[i]))
        ):
            free[i] = False
        if (
            upper is not None
            and np.isfinite(upper[i])
            and abs(coef[i] - upper[i]) <= 1e-9 * (1.0 + abs(upper[i]))
        ):
            free[i] = False
    if design.shape[1] != k or not free.any():
        return None
    resid = model.evaluate(coef, t, b) - th
    dof = len(t) - int(free.sum())
    if dof <= 0:
        return None
    x = design[:, free]
    weights = model.fit_weights(th, groups)
    try:
        if weights is None:
            inner = np.linalg.pinv(x.T @ x) * float(np.sum(resid**2) / dof)
        else:
            bread = np.linalg.pinv(x.T @ (x * weights[:, None]))
            meat = x.T @ (x * (weights**2 * resid**2)[:, None])
            inner = bread @ meat @ bread * (len(t) / dof)
    except np.linalg.LinAlgError:
        return None
    cov_c = np.zeros((k, k))
    cov_c[np.ix_(free, free)] = inner
    jac = np.column_stack([to_raw(e) for e in np.eye(k)])  # raw = J @ conditioned
    cov = jac @ cov_c @ jac.T
    return np.asarray(0.5 * (cov + cov.T), dtype=float) if np.all(np.isfinite(cov)) else None
