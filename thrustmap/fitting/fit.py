"""Fit thrust maps from Ds, validate them, and score maps on new data.

``fit_map``: selection -> model fit -> checks (monotone in T, conditioning) -> ``ThrustMap``.
``compare``: several models under one validation mode (in-sample, by-file, k-fold); the headline
counts every held-out point, with the points inside and outside the training points' supported
region beside it.
``evaluate``: an existing map against new files.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from thrustmap.core.errors import ConfigError, FitError, ThrustmapError
from thrustmap.core.units import ThrottleScale
from thrustmap.fitting.dataset import Dataset, FloatArray
from thrustmap.fitting.interval import Interval, Region, advice, interval_range, learn_interval
from thrustmap.fitting.mapfile import Box, ThrustMap, ValidityBox
from thrustmap.fitting.metrics import Coverage, ErrorStats, coverage, error_stats
from thrustmap.fitting.models import (
    MIN_RELATIVE_SPAN,
    SCALING_BACKEMF,
    Identification,
    Model,
    MotorModel,
    backemf_coefficients,
    get_model,
)
from thrustmap.fitting.names import DEFAULT_MODEL, VALIDATIONS, Loss, Validation
from thrustmap.fitting.selection import Points, Selection, select
from thrustmap.fitting.solve import condition_number, solve_gram
from thrustmap.fitting.voltages import measured_voltages

log = logging.getLogger(__name__)

ILL_CONDITIONED = 1e8


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


def _check_fit_data(model: Model, t: FloatArray, b: FloatArray, where: str) -> None:
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


def fit_coefficients(
    model: Model, t: FloatArray, b: FloatArray, th: FloatArray, loss: Loss, where: str = "<data>"
) -> FloatArray:
    return identify_coefficients(model, t, b, th, loss, where)[0]


def identify_coefficients(
    model: Model, t: FloatArray, b: FloatArray, th: FloatArray, loss: Loss, where: str = "<data>"
) -> tuple[FloatArray, Identification | None]:
    """Coefficients and how they were identified (which were set by physics, and why)."""
    _check_fit_data(model, t, b, where)
    coef, ident = model.identify(t, b, th, loss)
    if not np.all(np.isfinite(coef)):
        raise FitError(
            f"fit of '{model.name}' gave non-finite coefficients; the data cannot determine "
            "this model (record more levels or use a simpler model)",
            file=where,
        )
    return coef, ident


@dataclass
class FitOutcome:
    map: ThrustMap
    pool: Pool
    warnings: list[str] = field(default_factory=list)
    trust: str = ""  # where the map can be trusted (its prediction interval and box)
    more_data: str = ""  # where more data would help most
    weighting: str = ""  # how the points were weighed, when it was not one each


#: what each kind of selected point is called when its share of the fit is reported
KIND_NAMES = {
    "plateau": "plateaus",
    "ramp": "ramp samples",
    "ramp-pair": "paired ramp samples",
    "stair-pair": "paired stairs",
    "step-summary": "step rows",
    "sample": "raw samples",
}
#: the weighting is reported when the heaviest point counts this many times the lightest
REPORT_WEIGHT_RATIO = 2.0


def weighting_line(model: Model, data: Pool) -> str:
    """One line on how a weighted model shared the fit among the kinds of points ('' when the
    model does not weigh, or every point counts about the same)."""
    w = model.fit_weights(data.throttle_pct)
    if w is None or not len(w) or float(np.max(w)) <= REPORT_WEIGHT_RATIO * float(np.min(w)):
        return ""
    kinds = np.concatenate([np.asarray(p.kind) for p in data.points])  # pooled in this order
    total = float(np.sum(w))
    parts = []
    for k in dict.fromkeys(kinds.tolist()):  # in the order they first appear
        sel = kinds == k
        parts.append(
            f"{int(sel.sum())} {KIND_NAMES.get(k, k)} carry {100 * float(np.sum(w[sel])) / total:.0f} %"
        )
    return (
        "fit weights: each point counts for the command range it covers, not one each: "
        + ", ".join(parts)
    )


def systematic_terms(points: Sequence[Points]) -> list[tuple[float, str]]:
    """What the stand showed beyond the residuals, for the interval: half the largest
    disagreement between a staircase's up and down legs at equal thrust (95th percentile)."""
    legs = [
        p.leg_disagreement_pct
        for p in points
        if isinstance(p, Points) and p.leg_disagreement_pct > 0  # (a test's Pool may hold None)
    ]
    if not legs:
        return []
    return [(0.5 * max(legs), "half the staircase legs' disagreement at equal thrust")]


def bound_term(
    m: Model, coef: FloatArray, t: FloatArray, b: FloatArray, th: FloatArray, loss: Loss
) -> list[tuple[float, str]]:
    """A coefficient resting on its bound is set by the bound, not the data: the interval
    carries what freeing it would change (95th percentile over the points)."""
    if not isinstance(m, MotorModel) or len(t) < m.n_coefficients:
        return []
    which = m.on_bound(coef, skip=(1, 2, 3))
    if not which:
        return []
    try:
        free = m.released_fit(t, b, th, loss, coef)
    except FitError:
        return []
    delta = np.abs(m.evaluate(free, t, b) - m.evaluate(coef, t, b))
    if not np.all(np.isfinite(delta)):
        return []
    return [(float(np.percentile(delta, 95)), f"{which}: what freeing it would change")]


def model_interval(
    m: Model,
    coef: FloatArray,
    t: FloatArray,
    b: FloatArray,
    th: FloatArray,
    file_index: np.ndarray[Any, np.dtype[np.int64]],
    loss: Loss,
    ident: Identification | None = None,
    systematic: Sequence[tuple[float, str]] = (),
    file_fit: Callable[[int], Callable[[FloatArray, FloatArray], FloatArray]] | None = None,
) -> Interval | None:
    """The map's one 95 % prediction interval (fitting.interval.learn_interval) for model ``m``
    fitted with ``coef`` on these points: what ``fit`` writes, and what ``compare`` scores
    each fold's map with."""

    def predictor(
        tt: FloatArray, bb: FloatArray, tth: FloatArray
    ) -> Callable[[FloatArray, FloatArray], FloatArray]:
        c = fit_coefficients(m, tt, bb, tth, loss)
        return lambda tq, bq: m.evaluate(c, tq, bq)

    pred = m.evaluate(coef, t, b)
    return learn_interval(
        t,
        b,
        th,
        file_index,
        predictor,
        np.abs(pred - th),
        Region.from_points(t, b),
        parameter_covariance(m, coef, t, b, th, ident),
        file_fit,
        [*systematic, *bound_term(m, coef, t, b, th, loss)],
    )


def fit_map(
    datasets: Sequence[Dataset],
    *,
    model: str = DEFAULT_MODEL,
    loss: Loss = "l2",
    selection: Selection | None = None,
    strategy: str | None = None,
) -> FitOutcome:
    selection = selection or Selection()
    m = get_model(model)
    data = pool(datasets, selection)
    where = ", ".join(d.path for d in datasets)
    coef, ident = identify_coefficients(
        m, data.thrust_n, data.voltage_v, data.throttle_pct, loss, where
    )
    file_fit = None
    if isinstance(m, MotorModel):
        coef, ident = _voltage_term_by_file(m, data, loss, coef, ident)
    if m.name == "motor":
        coef, ident, file_fit = _try_backemf(datasets, data, selection, m, loss, coef, ident)
    pred = m.evaluate(coef, data.thrust_n, data.voltage_v)
    stats = error_stats(pred, data.throttle_pct)

    region = Region.from_points(data.thrust_n, data.voltage_v)
    interval = model_interval(
        m,
        coef,
        data.thrust_n,
        data.voltage_v,
        data.throttle_pct,
        data.file_index,
        loss,
        ident,
        systematic_terms(data.points),
        file_fit,
    )
    over_region = None if interval is None else interval_range(interval, m.design)
    trust, more_data = advice(
        interval,
        region,
        over_region,
        data.thrust_n,
        data.voltage_v,
        physics_voltage=ident is not None and bool(ident.fixed),
        few_points=ident is not None and ident.limited_by == "points",
    )
    box = ValidityBox(
        thrust_n=Box(float(data.thrust_n.min()), float(data.thrust_n.max())),
        voltage_v=Box(float(data.voltage_v.min()), float(data.voltage_v.max())),
        throttle_pct=Box(float(data.throttle_pct.min()), float(data.throttle_pct.max())),
    )
    rotors = {d.rotors_on_esc for d in datasets}
    rotors_on_esc = rotors.pop() if len(rotors) == 1 else None
    if strategy is None:
        strategy = "LA" if m.name == "la" else {1: "SR", 4: "MR"}.get(rotors_on_esc or 0, "unknown")
    tmap = ThrustMap(
        model=m.name,
        coefficients=tuple(float(c) for c in coef),
        throttle_scale=data.scale,
        validity=box,
        loss=loss,
        strategy=strategy,
        rotors_on_esc=rotors_on_esc,
        metrics={"in_sample": stats.to_dict()},
        selection={
            **selection.to_dict(),
            # which voltages the map was measured at (issue 30 item 4)
            "measured_voltages_v": measured_voltages(data.voltage_v),
            "report": [p.report for p in data.points],
        },
        sources=tuple(d.source_record() for d in datasets),
        identification={} if ident is None else ident.to_dict(),
        interval={}
        if interval is None or over_region is None
        else {**interval.to_dict(), "over_region_pct": list(over_region)},
        supported=region,
        spin_up=spin_up_block(datasets),
    )
    if ident is not None:
        log.info("%s: %s", m.name, ident.reason)
    warnings = check_map(tmap, data)
    for w in warnings:
        log.info("%s", w)  # returned to the caller, who shows them
    return FitOutcome(tmap, data, warnings, trust, more_data, weighting_line(m, data))


#: the fitted voltage term is kept only when it holds out better by file than this share of the
#: physics prior's error (a tie, or a fold that cannot fit it, keeps the prior)
VOLTAGE_TERM_MARGIN = 0.98


def _voltage_term_by_file(
    m: MotorModel, data: Pool, loss: Loss, coef: FloatArray, ident: Identification | None
) -> tuple[FloatArray, Identification | None]:
    """A voltage term (k0) fitted on points of several files is kept only if leave-one-file-out
    confirms it: each file is predicted by the identification fitted on the other files, and by
    the physics prior (k0 = 0) fitted on them. Files recorded on different days differ for
    reasons other than voltage (a load-cell offset, a warmer motor, another propeller mount),
    which an in-sample fit reads as a voltage term."""
    files = np.unique(data.file_index)
    if ident is None or ident.form != "full" or len(files) < 2:
        return coef, ident
    err_fit: list[FloatArray] = []
    err_prior: list[FloatArray] = []
    for f in files:
        test = data.file_index == f
        t, b, th = data.take(~test)
        tt, bt, tht = data.take(test)
        try:
            c_fit = identify_coefficients(m, t, b, th, loss)[0]
            c_prior = m.physics_fit(t, b, th, loss, "", "")[0]
        except FitError:
            c_fit = c_prior = np.full(m.n_coefficients, np.nan)
        if not (np.all(np.isfinite(c_fit)) and np.all(np.isfinite(c_prior))):
            err_fit.append(np.full(len(tt), np.inf))
            err_prior.append(np.zeros(len(tt)))
            continue
        err_fit.append(np.abs(m.evaluate(c_fit, tt, bt) - tht))
        err_prior.append(np.abs(m.evaluate(c_prior, tt, bt) - tht))
    e_fit = float(np.mean(np.concatenate(err_fit)))
    e_prior = float(np.mean(np.concatenate(err_prior)))
    evidence = {
        **ident.evidence,
        "by_file_voltage_term_pct": e_fit,
        "by_file_physics_prior_pct": e_prior,
    }
    if e_fit < VOLTAGE_TERM_MARGIN * e_prior:
        note = f"; confirmed by file (held out {e_fit:.3f} % against {e_prior:.3f} % with k0 = 0)"
        return coef, replace(ident, reason=ident.reason + note, evidence=evidence)
    shown = "could not be fitted without one file" if not np.isfinite(e_fit) else f"{e_fit:.3f} %"
    reason = (
        f"voltage span {ident.voltage_span_v:.2f} V across {len(files)} files, but the voltage "
        f"term fitted on the others held out no better by file ({shown} against {e_prior:.3f} % "
        "with k0 = 0; files from different days differ for reasons other than voltage): the "
        "physics prior (k0 = 0) is used"
    )
    t, b, th = data.thrust_n, data.voltage_v, data.throttle_pct
    evidence = {k: v for k, v in evidence.items() if np.isfinite(v)}
    return m.physics_fit(t, b, th, loss, reason, "files", evidence)


def spin_up_block(datasets: Sequence[Dataset]) -> dict[str, Any]:
    """The map's ``spin_up`` block: the lowest command the raw samples show spinning."""
    from thrustmap.fitting.spinup import spin_up

    return spin_up(datasets).to_dict()


Predictor = Callable[[FloatArray, FloatArray], FloatArray]


def backemf_rows(ds: Dataset, sel: Selection) -> tuple[FloatArray, ...] | None:
    """(throttle %, thrust, voltage, rpm, current) of a file's rows inside the selection's
    ranges; None when the file logged no rpm or no current."""
    if ds.rpm is None or ds.current_a is None:
        return None
    keep = np.ones(len(ds), bool)
    for rng, x in (
        (sel.throttle_range, ds.throttle_native),
        (sel.voltage_range, ds.voltage_v),
        (sel.thrust_range, ds.thrust_n),
    ):
        if rng is not None:
            keep &= (x > rng[0]) & (x < rng[1])
    pct = ds.throttle_scale.to_pct(ds.throttle_native)
    return (pct[keep], ds.thrust_n[keep], ds.voltage_v[keep], ds.rpm[keep], ds.current_a[keep])


def _try_backemf(
    datasets: Sequence[Dataset],
    data: Pool,
    sel: Selection,
    m: Model,
    loss: Loss,
    coef: FloatArray,
    ident: Identification | None,
) -> tuple[FloatArray, Identification | None, Callable[[int], Predictor] | None]:
    """Where every file logged rpm and current, try the back-EMF scaling (models.
    backemf_coefficients) and keep it only if by-file held-out error confirms it: each file is
    predicted by both identifications fitted on the other files. Needs files at two or more
    voltages; otherwise the map keeps its identification and says the trial could not be
    judged. Returns the coefficients, the identification and, when kept, the by-file refit."""
    rows = [backemf_rows(d, sel) for d in datasets]
    if ident is None or any(r is None for r in rows):
        return coef, ident, None
    have = [r for r in rows if r is not None]

    def bemf(files: Sequence[int]) -> FloatArray | None:
        cols = [np.concatenate([have[f][k] for f in files]) for k in range(5)]
        return backemf_coefficients(*cols)

    means = np.array([float(np.mean(d.voltage_v)) for d in datasets])
    spread = float(np.ptp(means)) / float(np.mean(means)) if len(means) else 0.0
    if len(datasets) < 2 or spread < MIN_RELATIVE_SPAN:
        note = (
            "; rpm and current logged: the back-EMF scaling (B·d = Ke·ω + R·I) was not tried, "
            "as only files at another voltage could confirm it held out"
        )
        return coef, replace(ident, scaling=ident.scaling + note), None
    err_t: list[FloatArray] = []
    err_b: list[FloatArray] = []
    for i in range(len(datasets)):
        test = data.file_index == i
        others = [f for f in range(len(datasets)) if f != i]
        t, b, th = data.take(~test)
        tt, bt, tht = data.take(test)
        cb = bemf(others)
        if cb is None or len(t) < m.n_coefficients:
            return coef, ident, None
        try:
            ct = fit_coefficients(m, t, b, th, loss)
        except FitError:
            return coef, ident, None
        err_t.append(np.abs(m.evaluate(ct, tt, bt) - tht))
        err_b.append(np.abs(m.evaluate(cb, tt, bt) - tht))
    e_t = float(np.mean(np.concatenate(err_t)))
    e_b = float(np.mean(np.concatenate(err_b)))
    full = bemf(range(len(datasets)))
    evidence = {"held_out_backemf_pct": e_b, "held_out_thrust_form_pct": e_t}
    if full is None or not e_b < e_t:
        note = (
            f"; back-EMF scaling from the logged rpm and current tried and not kept (held-out "
            f"by file {e_b:.3f} % against {e_t:.3f} %)"
        )
        return (
            coef,
            replace(ident, scaling=ident.scaling + note, evidence={**ident.evidence, **evidence}),
            None,
        )
    reason = (
        f"{ident.reason}; rpm and current logged: the back-EMF scaling held out better by file "
        f"({e_b:.3f} % against {e_t:.3f} %) and is used (k0 = R·I0 = {full[1]:.3g} measured)"
    )
    kept = Identification(
        "back-EMF", reason, ident.voltage_span_v, (), evidence, "", SCALING_BACKEMF
    )

    def file_fit(held: int) -> Predictor:
        cb = bemf([f for f in range(len(datasets)) if f != held])
        if cb is None:
            raise FitError("back-EMF fold could not be fitted")
        return lambda tq, bq: m.evaluate(cb, tq, bq)

    return full, kept, file_fit


def parameter_covariance(
    model: Model,
    coef: FloatArray,
    t: FloatArray,
    b: FloatArray,
    th: FloatArray,
    ident: Identification | None,
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
    weights = model.fit_weights(th)
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


def check_map(tmap: ThrustMap, data: Pool | None = None) -> list[str]:
    """Warnings a user must see: not monotone in T inside the box, ill-conditioned fit."""
    out: list[str] = []
    tt, bb = tmap.supported_region().grid(101)  # rows: one voltage each, thrust ascending
    th = tmap.throttle_pct(tt, bb, corrected=False)
    d = np.diff(th, axis=1)
    if (d < -1e-9).any():
        i, j = np.unravel_index(int(np.argmin(d)), d.shape)
        out.append(
            f"map '{tmap.model}' is not monotone in thrust over its supported region "
            f"(throttle falls near T={tt[i, j]:.2f} N, B={bb[i, j]:.2f} V): more thrust would be "
            "commanded with less throttle"
        )
    if data is not None:
        m = tmap.model_def
        cond = condition_number(m.conditioned(data.thrust_n, data.voltage_v)[0])
        if cond > ILL_CONDITIONED:
            out.append(
                f"fit of '{m.name}' is ill-conditioned (condition number {cond:.2e}); "
                "coefficients are poorly determined by this data"
            )
    return out


# -- validation --------------------------------------------------------------------------------


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
            _check_fit_data(m, t, b, f"{model} {validation} fold")
            dt = design[test]
            if weighted:
                w = np.zeros(n)
                w[train] = m.fit_weights(th)
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
            coef = fit_coefficients(m, t, b, th, loss, where=f"{model} {validation} fold")
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
            t,
            b,
            th,
            data.file_index[train],
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
    return rows
