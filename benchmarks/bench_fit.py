"""Fit + by-file validation on 1 000 000 synthetic stand samples, beside the paper's method.

The paper's scripts fit µs = f(T, B) with scipy.optimize.curve_fit over all samples. Here the
same data goes through thrustmap's pipeline: steady-state extraction over 10 files, the default
model's fit, and leave-one-file-out validation. Run: python benchmarks/bench_fit.py [N]
"""

from __future__ import annotations

import sys
import time

import numpy as np
from scipy.optimize import curve_fit

from thrustmap.core.units import SCALES
from thrustmap.fitting.dataset import Dataset
from thrustmap.fitting.fit.fitmap import fit_map
from thrustmap.fitting.fit.validation import validate
from thrustmap.fitting.selection.options import Selection


def synthetic(n_total: int, files: int = 10, seed: int = 0) -> list[Dataset]:
    """Step sweeps at 100 Hz: plateaus with first-order settling, noise, battery sag."""
    rng = np.random.default_rng(seed)
    out = []
    per = n_total // files
    for f in range(files):
        t = np.arange(per) * 0.01
        level = 1100 + 50 * ((np.arange(per) // 300) % 14)  # 3 s plateaus, 1100..1750 µs
        u = (level - 1000) / 1000.0
        volt = 25.0 - 0.4 * f - 3.0 * t / t[-1] - 1.5 * u**2
        thrust_ss = 14.0 * (u * volt / 25.0) ** 2
        step_start = (np.arange(per) // 300) * 300
        settle = 1 - np.exp(-(np.arange(per) - step_start) * 0.01 / 0.08)
        thrust = thrust_ss * settle + rng.normal(0, 0.02, per)
        out.append(
            Dataset(
                path=f"synthetic-{f}.csv",
                format="synthetic",
                throttle_scale=SCALES["pwm"],
                throttle_native=level.astype(float),
                thrust_n=thrust,
                voltage_v=volt,
                line=np.arange(per, dtype=np.int64) + 2,
                time_s=t,
            )
        )
    return out


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 1_000_000
    data = synthetic(n)

    t0 = time.perf_counter()
    outcome = fit_map(data)  # steady-state selection + default model fit + checks
    row = validate(outcome.pool, outcome.map.model, "by-file")
    ours_s = time.perf_counter() - t0

    t0 = time.perf_counter()
    raw = fit_map(data, selection=Selection(all_samples=True))
    raw_row = validate(raw.pool, raw.map.model, "by-file")
    raw_s = time.perf_counter() - t0

    t_all = np.concatenate([d.thrust_n for d in data])
    b_all = np.concatenate([d.voltage_v for d in data])
    us_all = np.concatenate([d.throttle_native for d in data])

    def poly2(
        x: tuple[np.ndarray, np.ndarray], a: float, b: float, c: float, d: float, e: float, f: float
    ) -> np.ndarray:
        return a + b * x[0] + c * x[1] + d * x[0] ** 2 + e * x[0] * x[1] + f * x[1] ** 2

    t0 = time.perf_counter()
    curve_fit(poly2, (t_all, b_all), us_all)  # the paper's method: one fit, no validation
    paper_s = time.perf_counter() - t0

    print(f"samples: {n:,} in {len(data)} files")
    print(
        f"thrustmap  steady-state + '{outcome.map.model}' fit + by-file validation: {ours_s:6.3f} s "
        f"(held-out mean e_Th {row.all.mean_pct:.3f} % over all {row.all.n} held-out points)"
    )
    print(
        f"thrustmap  --all-samples '{raw.map.model}' fit + by-file validation:        {raw_s:6.3f} s "
        f"(held-out mean e_Th {raw_row.all.mean_pct:.3f} %, transients included)"
    )
    print(f"paper      scipy curve_fit poly2 over all samples (no validation):   {paper_s:6.3f} s")
    print(f"goal: under 2 s -> {'met' if max(ours_s, raw_s) < 2.0 else 'NOT met'}")


if __name__ == "__main__":
    main()
