"""``fit_map``: selection -> model fit (the voltage term confirmed by file, the back-EMF
scaling tried) -> the map's 95 % interval and supported region -> checks -> ``ThrustMap``."""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

import numpy as np

from thrustmap.core.errors import FitError
from thrustmap.fitting.dataset import Dataset, FloatArray, IntArray
from thrustmap.fitting.fit.advice import advice
from thrustmap.fitting.fit.backemf import try_backemf
from thrustmap.fitting.fit.coefficients import (
    Pool,
    fit_coefficients,
    identify_coefficients,
    parameter_covariance,
    pool,
)
from thrustmap.fitting.interval import (
    Interval,
    IntervalTerms,
    Region,
    interval_range,
    learn_interval,
)
from thrustmap.fitting.mapfile import Box, ThrustMap, ValidityBox
from thrustmap.fitting.metrics import error_stats
from thrustmap.fitting.models import Identification, Model, MotorModel, get_model
from thrustmap.fitting.names import DEFAULT_MODEL, Loss
from thrustmap.fitting.selection.options import Selection
from thrustmap.fitting.selection.points import Points
from thrustmap.fitting.solve import condition_number
from thrustmap.fitting.voltages import measured_voltages

log = logging.getLogger(__name__)


ILL_CONDITIONED = 1e8


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
    w = model.fit_weights(data.throttle_pct, data.file_index)
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
        "fit weights: each file counts for the command range it covers, and each of its points "
        "for its share of that range, not one each (a ramp's thousand samples do not outvote "
        "a staircase's plateaus over the same range): " + ", ".join(parts)
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
    m: Model,
    coef: FloatArray,
    t: FloatArray,
    b: FloatArray,
    th: FloatArray,
    loss: Loss,
    groups: IntArray | None = None,
) -> list[tuple[float, str]]:
    """A coefficient resting on its bound is set by the bound, not the data: the interval
    carries what freeing it would change (95th percentile over the points)."""
    if not isinstance(m, MotorModel) or len(t) < m.n_coefficients:
        return []
    which = m.on_bound(coef, skip=(1, 2, 3))
    if not which:
        return []
    try:
        free = m.released_fit(t, b, th, loss, coef, groups)
    except FitError:
        return []
    delta = np.abs(m.evaluate(free, t, b) - m.evaluate(coef, t, b))
    if not np.all(np.isfinite(delta)):
        return []
    return [(float(np.percentile(delta, 95)), f"{which}: what freeing it would change")]


class FittedPoints(NamedTuple):
    """The points a model was fitted on: thrust, voltage, throttle and each one's file."""

    thrust_n: FloatArray
    voltage_v: FloatArray
    throttle_pct: FloatArray
    file_index: np.ndarray[Any, np.dtype[np.int64]]


def model_interval(
    m: Model,
    coef: FloatArray,
    points: FittedPoints,
    loss: Loss,
    ident: Identification | None = None,
    systematic: Sequence[tuple[float, str]] = (),
    file_fit: Callable[[int], Callable[[FloatArray, FloatArray], FloatArray]] | None = None,
) -> Interval | None:
    """The map's one 95 % prediction interval (fitting.interval.learn_interval) for model ``m``
    fitted with ``coef`` on ``points``: what ``fit`` writes, and what ``compare`` scores each
    fold's map with."""
    t, b, th, file_index = points

    def predictor(
        tt: FloatArray, bb: FloatArray, tth: FloatArray, files: IntArray
    ) -> Callable[[FloatArray, FloatArray], FloatArray]:
        c = fit_coefficients(m, tt, bb, tth, loss, groups=files)
        return lambda tq, bq: m.evaluate(c, tq, bq)

    pred = m.evaluate(coef, t, b)
    terms = IntervalTerms(
        region=Region.from_points(t, b),
        covariance=parameter_covariance(m, coef, t, b, th, ident, file_index),
        file_fit=file_fit,
        systematic=[*systematic, *bound_term(m, coef, t, b, th, loss, file_index)],
    )
    return learn_interval(t, b, th, file_index, predictor, np.abs(pred - th), terms)


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
        m, data.thrust_n, data.voltage_v, data.throttle_pct, loss, where, data.file_index
    )
    file_fit = None
    if isinstance(m, MotorModel):
        coef, ident = _voltage_term_by_file(m, data, loss, coef, ident)
    if m.name == "motor":
        coef, ident, file_fit = try_backemf(datasets, data, selection, m, loss, coef, ident)
    pred = m.evaluate(coef, data.thrust_n, data.voltage_v)
    stats = error_stats(pred, data.throttle_pct)

    region = Region.from_points(data.thrust_n, data.voltage_v)
    interval = model_interval(
        m,
        coef,
        FittedPoints(data.thrust_n, data.voltage_v, data.throttle_pct, data.file_index),
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
        within_recording=None
        if interval is None
        else interval_range(interval, m.design, within_recording=True),
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
        saturation=saturation_block(data.points),
    )
    if ident is not None:
        log.info("%s: %s", m.name, ident.reason)
    warnings = [*top_warnings(data.points, tmap.saturation), *check_map(tmap, data)]
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
            groups = data.file_index[~test]
            c_fit = identify_coefficients(m, t, b, th, loss, groups=groups)[0]
            c_prior = m.physics_fit(t, b, th, loss, "", "", groups=groups)[0]
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


#: a file whose kept points reach this far (% throttle) above another file's saturation shows
#: the saturation is not the ESC's (the files disagree): no full-throttle thrust is read from it
SATURATION_AGREE_PCT = 1.0


def _tops(points: Sequence[Points]) -> list[tuple[str, dict[str, Any]]]:
    """(file, what ``selection.top`` found) for each file where it found a top."""
    return [
        (p.source, p.report["past_top"])
        for p in points
        if isinstance(p.report.get("past_top"), dict)
    ]


def saturation_block(points: Sequence[Points]) -> dict[str, Any]:
    """The map's ``saturation`` block: the lowest command at which a file's thrust stopped
    rising because the ESC's output saturated (``selection.top``), when no other file's points
    reach above it; empty otherwise."""
    sats = [(name, float(c["knee_throttle_pct"])) for name, c in _tops(points)
            if c.get("kind") == "saturation"]  # fmt: skip
    if not sats:
        return {}
    knee = min(k for _, k in sats)
    if any(len(p) and float(p.throttle_pct.max()) > knee + SATURATION_AGREE_PCT for p in points):
        return {}
    return {
        "throttle_pct": round(knee, 4),
        "files": [name for name, _ in sats],
        "reason": "thrust stopped rising with the command (selection.top)",
    }


def top_warnings(points: Sequence[Points], saturation: dict[str, Any]) -> list[str]:
    """One warning per file whose points past the top of its thrust curve were left out, and
    one when the files disagree on a saturation."""
    from thrustmap.fitting.selection.top import TopCut

    tops = _tops(points)
    out = [f"{name}: {TopCut.describe(c)}" for name, c in tops]
    if any(c.get("kind") == "saturation" for _, c in tops) and not saturation:
        out.append(
            "a file saturated where another file's thrust still rose: the full-throttle thrust "
            "is not read from the saturation (were the ESC's end points recalibrated between "
            "the recordings?)"
        )
    return out


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
