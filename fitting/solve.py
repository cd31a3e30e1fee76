"""Linear-in-parameters solvers: least squares and exact least absolute deviations.

Both take a design matrix whose columns are already well scaled (see models.py). The L1 fit
is the seed paper's eq. (8) solved exactly as a linear program (HiGHS), not approximated.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import numpy.typing as npt
import scipy.optimize as opt
import scipy.sparse as sp

from thrustmap.errors import FitError

FloatArray = npt.NDArray[np.float64]
Loss = Literal["l2", "l1"]
LOSSES: tuple[Loss, ...] = ("l2", "l1")


def solve(
    design: FloatArray,
    target: FloatArray,
    *,
    loss: Loss = "l2",
    lower: FloatArray | None = None,
) -> FloatArray:
    """Coefficients c minimising ||design @ c - target|| in the L2 or L1 sense.

    ``lower`` gives per-coefficient lower bounds (-inf for none); used to keep physics models
    monotone. Column scaling is applied internally so the bounds are in the caller's units.
    """
    n, k = design.shape
    if n < k:
        raise FitError(f"{n} samples cannot determine {k} coefficients; need at least {k}")
    norms = np.linalg.norm(design, axis=0)
    norms[norms == 0] = 1.0
    scaled = design / norms
    lo = None if lower is None else np.asarray(lower, dtype=float) * norms
    bounded = lo is not None and bool(np.isfinite(lo).any())
    if loss == "l2":
        if not bounded:
            coef, *_ = np.linalg.lstsq(scaled, target, rcond=None)
        else:
            assert lo is not None
            res = opt.lsq_linear(scaled, target, bounds=(lo, np.full(k, np.inf)), method="bvls")
            coef = res.x
    elif loss == "l1":
        coef = _lad(scaled, target, lo)
    else:
        raise FitError(f"unknown loss '{loss}'; expected one of: {', '.join(LOSSES)}")
    return np.asarray(coef / norms, dtype=float)


def _lad(a: FloatArray, y: FloatArray, lower: FloatArray | None) -> FloatArray:
    """Least absolute deviations as an LP: min sum(u+v) s.t. A c + u - v = y, u, v >= 0."""
    n, k = a.shape
    cost = np.concatenate([np.zeros(k), np.ones(2 * n)])
    eye = sp.identity(n, format="csr")
    a_eq = sp.hstack([sp.csr_matrix(a), eye, -eye], format="csr")
    lo = np.full(k, -np.inf) if lower is None else lower
    bounds = [(None if not np.isfinite(b) else float(b), None) for b in lo] + [(0.0, None)] * (
        2 * n
    )
    res = opt.linprog(cost, A_eq=a_eq, b_eq=y, bounds=bounds, method="highs")
    if res.status != 0:
        raise FitError(f"least-absolute-deviations LP did not solve: {res.message}")
    return np.asarray(res.x[:k], dtype=float)


def condition_number(design: FloatArray) -> float:
    """Condition number of the column-normalised design (what the solver actually sees)."""
    norms = np.linalg.norm(design, axis=0)
    norms[norms == 0] = 1.0
    s = np.linalg.svd(design / norms, compute_uv=False)
    return float(s[0] / s[-1]) if s[-1] > 0 else float("inf")
