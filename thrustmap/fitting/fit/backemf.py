"""The back-EMF scaling (B·d = Ke·ω + R·I) from logged rpm and current, kept only when it
holds out better by file."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from thrustmap.core.errors import FitError
from thrustmap.fitting.dataset import Dataset, FloatArray
from thrustmap.fitting.fit.coefficients import Pool, fit_coefficients
from thrustmap.fitting.models import (
    MIN_RELATIVE_SPAN,
    SCALING_BACKEMF,
    Identification,
    Model,
    backemf_coefficients,
)
from thrustmap.fitting.names import Loss
from thrustmap.fitting.selection.options import Selection

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


def try_backemf(
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
