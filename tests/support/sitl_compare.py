"""The acceptance numbers of one SITL flight (tests/support/sitl_flight.py made OUT_DIR):

    python -m support.sitl_compare OUT_DIR LOG --mass-kg M

- samples `gamma live` kept (its Df) against those `flightlog extract` keeps from the SITL's own
  log of the same flight (.BIN / .ulg), and the ratio;
- γ(B) of `gamma live` against `gamma fit` on the log's Df, as the largest relative difference
  over the voltages both cover (41 points);
- the hover throttle from the live Df (median of command·g/a_up) against PX4's hover-thrust
  estimate in the log's Df (median), when the log has one;
- `gamma live replay://` of the recording against the live run (largest coefficient difference).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

from support.sitl_flight import _env


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "thrustmap", *args], cwd=cwd, env=_env(), capture_output=True,
        text=True, timeout=600,
    )  # fmt: skip


def _gamma(path: Path) -> tuple[list[float], list[float]] | None:
    if not path.exists():
        return None
    corr = json.loads(path.read_text()).get("correction")
    return None if corr is None else (corr["coefficients"], corr["voltage_v"])


def compare(out: Path, log: Path, mass_kg: float) -> dict[str, Any]:
    from thrustmap.fitting.df.dffile import read_df
    from thrustmap.fitting.df.table import hover_throttle

    res: dict[str, Any] = {}
    ext = _cli("flightlog", "extract", str(log), "--map", "map.json", "--mass-kg", str(mass_kg),
               "-o", "log.csv", cwd=out)  # fmt: skip
    res["extract_exit"] = ext.returncode
    fit = _cli("gamma", "fit", "log.csv", "--map", "map.json", "-o", "logfit.json", cwd=out)
    res["fit_exit"] = fit.returncode
    rep = _cli("gamma", "live", "replay://live.tlog", "--map", "map.json", "--mass-kg",
               str(mass_kg), "-o", "replay.json", "--df", "replay.csv", cwd=out)  # fmt: skip
    res["replay_exit"] = rep.returncode
    live_df, _ = read_df(out / "live.df.csv")
    log_df, _ = read_df(out / "log.csv")
    res["samples_live"], res["samples_log"] = len(live_df), len(log_df)
    res["kept_ratio"] = len(live_df) / max(len(log_df), 1)
    g_live, g_log, g_rep = (_gamma(out / n) for n in ("live.json", "logfit.json", "replay.json"))
    if g_live and g_log:
        lo = max(g_live[1][0], g_log[1][0])
        hi = min(g_live[1][1], g_log[1][1])
        b = np.linspace(lo, hi, 41) if hi >= lo else np.array([])
        a = np.polynomial.polynomial.polyval(np.clip(b, *g_live[1]), g_live[0])
        c = np.polynomial.polynomial.polyval(np.clip(b, *g_log[1]), g_log[0])
        res["voltage_both_v"] = [float(lo), float(hi)] if len(b) else None
        res["gamma_live"], res["gamma_log"] = g_live, g_log
        res["gamma_max_rel_diff"] = float(np.max(np.abs(a / c - 1))) if len(b) else None
    if g_live and g_rep:
        res["replay_max_coef_diff"] = float(np.max(np.abs(np.subtract(g_live[0], g_rep[0]))))
    if "thrust_cmd_norm" in live_df.columns and len(live_df):
        res["hover_ours"] = hover_throttle(live_df)
    if "hover_thrust_est" in log_df.columns and len(log_df):
        res["hover_estimate"] = float(np.nanmedian(log_df["hover_thrust_est"]))
        if "hover_ours" in res:
            res["hover_diff"] = abs(res["hover_ours"] - res["hover_estimate"])
    return res


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("out", type=Path)
    ap.add_argument("log", type=Path)
    ap.add_argument("--mass-kg", type=float, required=True)
    a = ap.parse_args()
    print(json.dumps(compare(a.out, a.log, a.mass_kg), default=float))


if __name__ == "__main__":
    main()
