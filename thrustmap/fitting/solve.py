"""Linear-in-parameters solvers: least squares and exact least absolute deviations.

Both take a design matrix whose columns are already well scaled (see models.py). The L1 fit
is the seed paper's eq. (8) solved exactly as a linear program (HiGHS), not approximated.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import TypeVar

import numpy as np
import numpy.typing as npt

from thrustmap.core.errors import FitError
from thrustmap.fitting.names import LOSSES, Loss

FloatArray = npt.NDArray[np.float64]
T = TypeVar("T")

#: progress of a long computation: the CLI shows these records at once, on stderr
progress_log = logging.getLogger("thrustmap.progress")  # (cli.PROGRESS_LOGGER)
#: a computation still running after this long says so, and again every as long
PROGRESS_EVERY_S = 5.0
#: how often the waiting thread wakes: Ctrl-C is acted on within this
WAKE_S = 0.1
#: LPs this large count towards the progress lines (a γ fit's few hundred samples, refitted
#: again and again by `gamma live`, never print one)
PROGRESS_MIN_POINTS = 2000


class _Heartbeat:
    """The time spent in long computations in this process, and when that was last said: a
    command of many solves (a fit, then each fold of its interval) says where it is every
    ``PROGRESS_EVERY_S`` of solving, however short each solve is."""

    def __init__(self) -> None:
        self.solving_s = 0.0
        self.unsaid_s = 0.0

    def tick(self, dt_s: float, what: str) -> None:
        self.solving_s += dt_s
        self.unsaid_s += dt_s
        if self.unsaid_s >= PROGRESS_EVERY_S:
            self.unsaid_s = 0.0
            progress_log.info(
                "%s; %.0f s of solving so far (Ctrl-C stops it)", what, self.solving_s
            )


_heartbeat = _Heartbeat()


def interruptible(work: Callable[[], T], what: str) -> T:
    """``work()`` on a worker thread while this thread waits, waking every ``WAKE_S``: a Ctrl-C
    stops the command within a fraction of a second (HiGHS releases the GIL but never checks
    for signals: run in place, an LP of a few thousand points took half a minute to react),
    and solving that runs past ``PROGRESS_EVERY_S`` says what it is doing, every as long
    (``_Heartbeat``; ``what`` empty: never said). The worker is a daemon: an interrupted
    computation ends with the process."""
    box: dict[str, object] = {}

    def run() -> None:
        try:
            box["value"] = work()
        except BaseException as exc:  # handed to the waiting thread, raised there
            box["error"] = exc

    worker = threading.Thread(target=run, name="thrustmap-solve", daemon=True)
    last = time.monotonic()
    worker.start()
    while worker.is_alive():
        worker.join(WAKE_S)
        now = time.monotonic()
        if what:
            _heartbeat.tick(now - last, what)
        last = now
    if "error" in box:
        raise box["error"]  # type: ignore[misc]
    return box["value"]  # type: ignore[return-value]


def solve(
    design: FloatArray,
    target: FloatArray,
    *,
    loss: Loss = "l2",
    lower: FloatArray | None = None,
    upper: FloatArray | None = None,
    weights: FloatArray | None = None,
) -> FloatArray:
    """Coefficients c minimising ||design @ c - target|| in the L2 or L1 sense.

    ``lower`` / ``upper`` give per-coefficient bounds (∓inf for none); used to keep physics
    models physical. Column scaling is applied internally so the bounds are in the caller's units.
    ``weights`` (> 0, one per row) weigh each row's squared (L2) or absolute (L1) residual.
    """
    import scipy.optimize as opt  # scipy loads when a fit runs (~1.5 s of imports)

    n, k = design.shape
    if n < k:
        raise FitError(f"{n} samples cannot determine {k} coefficients; need at least {k}")
    if weights is not None:
        row = np.sqrt(weights) if loss == "l2" else np.asarray(weights, float)
        design, target = design * row[:, None], target * row
    norms = np.linalg.norm(design, axis=0)
    norms[norms == 0] = 1.0
    scaled = design / norms
    lo = np.full(k, -np.inf) if lower is None else np.asarray(lower, dtype=float) * norms
    hi = np.full(k, np.inf) if upper is None else np.asarray(upper, dtype=float) * norms
    if loss == "l2":
        coef, *_ = np.linalg.lstsq(scaled, target, rcond=None)
        if np.any(coef < lo) or np.any(coef > hi):
            # Bounded least squares on the k x k triangular factor: same optimum, as
            # ||A c - y||² = ||R c - Qᵀy||² + const, and independent of the sample count.
            q, r = np.linalg.qr(scaled)
            res = opt.lsq_linear(r, q.T @ target, bounds=(lo, hi), method="bvls")
            coef = res.x
    elif loss == "l1":
        coef = _lad(scaled, target, lo, hi)
    else:
        raise FitError(f"unknown loss '{loss}'; expected one of: {', '.join(LOSSES)}")
    # the bounds hold exactly in the caller's units (unscaling may leave -1e-14 below 0)
    return np.asarray(np.clip(coef / norms, lo / norms, hi / norms), dtype=float)


def _lad(
    a: FloatArray, y: FloatArray, lower: FloatArray | None, upper: FloatArray | None = None
) -> FloatArray:
    """Least absolute deviations as an LP: min sum(u+v) s.t. A c + u - v = y, u, v >= 0."""
    import scipy.optimize as opt
    import scipy.sparse as sp

    n, k = a.shape
    cost = np.concatenate([np.zeros(k), np.ones(2 * n)])
    eye = sp.identity(n, format="csr")
    a_eq = sp.hstack([sp.csr_matrix(a), eye, -eye], format="csr")
    lo = np.full(k, -np.inf) if lower is None else lower
    hi = np.full(k, np.inf) if upper is None else upper
    bounds = [
        (None if not np.isfinite(b) else float(b), None if not np.isfinite(u) else float(u))
        for b, u in zip(lo, hi, strict=True)
    ] + [(0.0, None)] * (2 * n)
    res = interruptible(
        lambda: opt.linprog(cost, A_eq=a_eq, b_eq=y, bounds=bounds, method="highs"),
        f"solving the exact L1 fit (an LP) over {n} points" if n >= PROGRESS_MIN_POINTS else "",
    )
    if res.status != 0:
        raise FitError(f"least-absolute-deviations LP did not solve: {res.message}")
    return np.asarray(res.x[:k], dtype=float)


def condition_number(design: FloatArray) -> float:
    """Condition number of the column-normalised design (what the solver actually sees)."""
    return gram_condition_number(design.T @ design)


def gram_condition_number(gram: FloatArray) -> float:
    d = np.sqrt(np.diag(gram))
    d[d == 0] = 1.0
    ev = np.linalg.eigvalsh(gram / np.outer(d, d))
    return float(np.sqrt(ev[-1] / ev[0])) if ev[0] > 0 else float("inf")


def solve_gram(
    gram: FloatArray,
    rhs: FloatArray,
    lower: FloatArray | None = None,
    upper: FloatArray | None = None,
) -> FloatArray:
    """Least squares from the normal equations G c = h (G = AᵀA, h = Aᵀy), with bounds.

    Lets validation fit many folds from per-file sums without touching the samples again.
    """
    import scipy.optimize as opt

    k = len(rhs)
    d = np.sqrt(np.diag(gram))
    d[d == 0] = 1.0
    gs = gram / np.outer(d, d)
    hs = rhs / d
    coef, *_ = np.linalg.lstsq(gs, hs, rcond=None)
    lo = np.full(k, -np.inf) if lower is None else np.asarray(lower, float) * d
    hi = np.full(k, np.inf) if upper is None else np.asarray(upper, float) * d
    if np.any(coef < lo) or np.any(coef > hi):
        chol = np.linalg.cholesky(
            gs + 1e-14 * np.eye(k)
        )  # gs = L Lᵀ; ||Ac-y||² = ||Lᵀc - L⁻¹h||² + const
        target = np.linalg.solve(chol, hs)
        coef = opt.lsq_linear(chol.T, target, bounds=(lo, hi), method="bvls").x
    return np.asarray(np.clip(coef / d, lo / d, hi / d), dtype=float)
