"""Throttle error e_Th = |Th − Th_hat| in % of the throttle range (seed paper eq. 3)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from thrustmap.fitting.dataset import FloatArray


@dataclass(frozen=True)
class ErrorStats:
    n: int
    mean_pct: float
    std_pct: float  # std of |e| (what the issue asks); the paper's ± is closer to rms_pct
    p95_pct: float
    max_pct: float
    rms_pct: float
    bias_pct: float  # mean signed error (prediction − truth)

    def to_dict(self) -> dict[str, float | int | None]:
        """JSON-ready: a figure that does not exist (no points) is None, never NaN."""
        return {
            k: (None if isinstance(v, float) and not math.isfinite(v) else v)
            for k, v in asdict(self).items()
        }


def error_stats(predicted_pct: FloatArray, actual_pct: FloatArray) -> ErrorStats:
    signed = np.asarray(predicted_pct, float) - np.asarray(actual_pct, float)
    if signed.size == 0:
        nan = float("nan")
        return ErrorStats(0, nan, nan, nan, nan, nan, nan)
    e = np.abs(signed)
    return ErrorStats(
        n=int(e.size),
        mean_pct=float(e.mean()),
        std_pct=float(e.std()),
        p95_pct=float(np.percentile(e, 95)),
        max_pct=float(e.max()),
        rms_pct=float(np.sqrt(np.mean(signed**2))),
        bias_pct=float(signed.mean()),
    )
