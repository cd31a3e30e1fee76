"""Per-airframe γ(B): the fleet's logs grouped by airframe, each group fitted as ``gamma fit``.

A group is the logs with one airframe key (autopilot, frame and motor outputs, the parameters
that shape the thrust curve, the mass when given: :func:`thrustmap.fleet.task.airframe_of`).
Each group's Df files are read with :func:`thrustmap.fitting.df.read_df` and fitted with
:func:`thrustmap.fitting.gamma.fit_gamma`, pooled exactly as ``thrustmap gamma fit DF...`` pools
them (same reader, same concatenation order, same degree rule), so a group's γ(B) is the one
``gamma fit`` gives on that group's Df files. Groups with too few logs or samples, or whose
flown voltage spans too little for a γ slope, are reported and not fitted.

Beside each fit: a band holding 95 % of the group's per-sample γ = T_c/F_m around γ(B)
(2.5th and 97.5th percentiles of the residuals; in-sample), and the held-out error of the
chosen degree.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from thrustmap.core.errors import ThrustmapError
from thrustmap.core.identity import Identity, describe_repeat
from thrustmap.fleet.task import Outcome, one_line

if TYPE_CHECKING:
    import pandas as pd

    from thrustmap.fitting.gamma import GammaFit
    from thrustmap.fitting.mapfile import ThrustMap

log = logging.getLogger(__name__)

DEFAULT_MIN_LOGS = 3
DEFAULT_MIN_SAMPLES = 100


@dataclass
class Group:
    key: str
    airframe: dict[str, Any]
    logs: list[str]  # paths, sorted
    df_paths: list[Path]  # one per distinct content, in the order of ``logs``
    samples: int
    voltage_v: tuple[float, float] | None  # flown range (None: no voltage in the Dfs)
    status: str = "not fitted"  # fitted | too small | too narrow | not fitted
    reason: str = ""
    fit: GammaFit | None = None
    band: tuple[float, float] | None = None  # residual percentiles 2.5, 97.5 around γ(B)
    warnings: list[str] = field(default_factory=list)

    @property
    def label(self) -> str:
        a = self.airframe
        mass = a.get("mass_kg")
        parts = [str(a.get("autopilot", "?")), f"{a.get('rotors') or '?'} rotors"]
        if mass is not None:
            parts.append(f"{float(mass):g} kg")
        return " ".join(parts) + f" [{self.key}]"

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "key": self.key,
            "label": self.label,
            "airframe": self.airframe,
            "logs": self.logs,
            "df": [str(p) for p in self.df_paths],
            "samples": self.samples,
            "voltage_v": None if self.voltage_v is None else list(self.voltage_v),
            "status": self.status,
            "reason": self.reason,
            "warnings": self.warnings,
        }
        if self.fit is not None:
            d["gamma"] = self.fit.to_dict()
            d["gamma_band_95"] = None if self.band is None else list(self.band)
        return d


def group_logs(outcomes: list[Outcome], out_dir: Path) -> list[Group]:
    """The extracted logs (status ok) by airframe key, groups sorted by key."""
    by_key: dict[str, list[Outcome]] = {}
    for o in outcomes:
        if o.status == "ok" and o.samples > 0 and o.airframe_key:
            by_key.setdefault(o.airframe_key, []).append(o)
    groups = []
    for key in sorted(by_key):
        members = sorted(by_key[key], key=lambda o: o.path)
        dfs: list[Path] = []
        seen: dict[str, Outcome] = {}
        samples = 0
        for o in members:
            first = seen.get(o.df_path)
            if first is not None:  # the same content under two names is one flight, once
                log.warning(
                    "%s", describe_repeat(Identity(first.path, first.sha256),
                                          Identity(o.path, o.sha256), "flight log")
                    + ": counted once",
                )  # fmt: skip
                continue
            seen[o.df_path] = o
            dfs.append(out_dir / o.df_path)
            samples += o.samples
        lo = [o.voltage_min_v for o in members if math.isfinite(o.voltage_min_v)]
        hi = [o.voltage_max_v for o in members if math.isfinite(o.voltage_max_v)]
        groups.append(
            Group(
                key=key,
                airframe=json.loads(members[0].airframe),
                logs=[o.path for o in members],
                df_paths=dfs,
                samples=samples,
                voltage_v=(min(lo), max(hi)) if lo and hi else None,
            )
        )
    return groups


def read_pooled(
    df_paths: list[Path], tmap: ThrustMap | None = None
) -> tuple[pd.DataFrame, dict[str, Any]]:
    """The Df files pooled as ``gamma fit DF...`` pools them (``fitting.df.pool``): repeats
    and a Df of another map refused, the tables concatenated in order."""
    from thrustmap.fitting.df.pool import pool_dfs

    return pool_dfs(df_paths, tmap, "the fleet's map")


def fit_pooled(
    df_paths: list[Path], tmap: ThrustMap | None, loss: str = "l1"
) -> tuple[GammaFit, tuple[float, float] | None]:
    """γ(B) on these Df files with ``gamma fit``'s rule, and the 95 % band of per-sample γ."""
    import numpy as np

    from thrustmap.fitting.gamma import GammaOptions, fit_gamma, thrust_command_n

    table, side = read_pooled(df_paths, tmap)
    fit = fit_gamma(table, side, tmap, GammaOptions(loss="l1" if loss == "l1" else "l2"))
    volt = table["voltage_v"].to_numpy(float)
    known = np.isfinite(volt) & (volt > 0)
    band = None
    if known.any():
        rows = table[known].reset_index(drop=True)
        t_cmd, _ = thrust_command_n(rows, side, tmap)
        force = rows["force_n"].to_numpy(float)
        b = rows["voltage_v"].to_numpy(float)
        ok = np.isfinite(t_cmd) & np.isfinite(force) & (force > 0) & (t_cmd > 0)
        if ok.sum() >= 10:
            res = t_cmd[ok] / force[ok] - fit.correction.gamma(b[ok])
            band = (float(np.percentile(res, 2.5)), float(np.percentile(res, 97.5)))
    return fit, band


def fleet_gamma(
    outcomes: list[Outcome],
    out_dir: Path,
    tmap: ThrustMap | None,
    *,
    loss: str = "l1",
    min_logs: int = DEFAULT_MIN_LOGS,
    min_samples: int = DEFAULT_MIN_SAMPLES,
    min_span_v: float | None = None,
) -> list[Group]:
    """Every airframe group, fitted or with the reason it was not."""
    from thrustmap.fitting.gamma import MIN_SLOPE_SPAN_V, physical_refusals

    span_min = MIN_SLOPE_SPAN_V if min_span_v is None else min_span_v
    groups = group_logs(outcomes, out_dir)
    for g in groups:
        if len(g.df_paths) < min_logs or g.samples < min_samples:
            g.status = "too small"
            g.reason = (
                f"{len(g.df_paths)} log{'s' if len(g.df_paths) != 1 else ''}, {g.samples} Df "
                f"samples (needs {min_logs} logs and {min_samples} samples)"
            )
            continue
        if g.voltage_v is None:
            g.status, g.reason = "too narrow", "no battery voltage in its logs"
            continue
        span = g.voltage_v[1] - g.voltage_v[0]
        if span < span_min:
            g.status = "too narrow"
            g.reason = (
                f"flown voltage spans {span:.2f} V ({g.voltage_v[0]:.2f}..{g.voltage_v[1]:.2f} V;"
                f" needs {span_min:g} V for γ to depend on B)"
            )
            continue
        try:
            fit, band = fit_pooled(g.df_paths, tmap, loss)
        except ThrustmapError as exc:
            g.status, g.reason = "not fitted", one_line(exc)
            continue
        # what `gamma fit` refuses (without --force) is refused here: a Df too short for a
        # γ fit, or a γ outside the physical band over the flown voltages
        refusals = physical_refusals(fit)
        if refusals:
            g.status = "refused"
            g.reason = "; ".join(refusals) + " (as `gamma fit` refuses it: no corrected map)"
            continue
        g.fit, g.band = fit, band
        g.status = "fitted"
        g.warnings = list(g.fit.warnings)
    return groups
