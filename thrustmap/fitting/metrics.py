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


@dataclass(frozen=True)
class Coverage:
    """How many held-out points a map's 95 % prediction interval contained, and how wide the
    interval was there (median half-width, % throttle)."""

    n: int
    covered: int
    median_half_width_pct: float

    @property
    def coverage_pct(self) -> float:
        return 100.0 * self.covered / self.n if self.n else float("nan")

    def to_dict(self) -> dict[str, float | int | None]:
        """JSON-ready: a figure without points is None, never NaN."""
        pct, width = self.coverage_pct, self.median_half_width_pct
        return {
            "n": self.n,
            "coverage_pct": pct if math.isfinite(pct) else None,
            "median_half_width_pct": width if math.isfinite(width) else None,
        }

    def describe(self) -> str:
        if not self.n:
            return "-"
        return f"{self.coverage_pct:.1f} % of {self.n} (median ±{self.median_half_width_pct:.2f} %)"


def coverage(
    predicted_pct: FloatArray, actual_pct: FloatArray, half_width_pct: FloatArray
) -> Coverage:
    """The share of points whose throttle lies within the prediction ± its half-width."""
    err = np.abs(np.asarray(predicted_pct, float) - np.asarray(actual_pct, float))
    hw = np.asarray(half_width_pct, float)
    if err.size == 0:
        return Coverage(0, 0, float("nan"))
    return Coverage(int(err.size), int(np.sum(err <= hw)), float(np.median(hw)))
