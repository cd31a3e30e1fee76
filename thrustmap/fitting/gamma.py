"""The correction factor γ(B) (seed paper eq. 9-11) and the Table-4 flight metrics.

γ_j = T_c,j / F_m,j per Df sample; γ(B) is a polynomial of degree 0-3 in the battery voltage,
fitted by least squares or least absolute deviations (eq. 11, exact LP). The degree is chosen by
held-out error: leave-one-flight-out when the Df holds several flights, otherwise contiguous
time blocks of the one flight. The one-standard-error rule picks it: the simplest degree whose
held-out error is within one standard error (over the folds) of the best one, so a higher
degree must be clearly better, not just better on this draw (the paper settled on degree 2
for the same reason). A degree needs ``MIN_SAMPLES_PER_COEF`` samples per coefficient, and a
slope needs ``MIN_SLOPE_SPAN_V`` of battery span: on a narrower span the automatic choice is
degree 0 and a warning says why.

γ never makes the map worse: the rule above chooses among the degrees whose corrected map is no
worse than the uncorrected one in any voltage bin with ``MIN_BIN_SAMPLES`` Df samples (in e_Th
when the map is given, else e_T). A degree that fails is reported with its bins and numbers
(``GammaFit.guard``); when none passes, γ = 1 is kept (the map stays as it was) and a warning
says why. A degree given explicitly is kept, its worse bins reported. Flights with different
mass or rotor count are not pooled
unless asked (``allow_mixed``): their γ need not be the same function of B.

Metrics (per sample, then mean ± std, overall and binned by voltage):
- e_Th = |Th − f̂(F_m/n, B)| before, |Th − f̂(γ(B)·F_m/n, B)| after (throttle %), where Th is the
  throttle actually sent: the mean motor output in the map's scale when the log has it,
  otherwise f̂(T_c/n, B), the throttle the uncorrected map sent for the command;
- e_T = |T_c − F_m| before, |T_c/γ(B) − F_m| after, in N and in % of F_m (eq. 14).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
import pandas as pd

from thrustmap.core.errors import ConfigError, DataFormatError, FitError
from thrustmap.core.physical import gamma_outside_band
from thrustmap.core.units import ThrottleScale
from thrustmap.fitting.df.options import MIN_DF_SAMPLES
from thrustmap.fitting.df.thrust import (
    map_extrapolation,
    motor_pct_in_map_scale,
    thrust_from_motors,
)
from thrustmap.fitting.mapfile import Box, GammaCorrection, ThrustMap
from thrustmap.fitting.names import Loss
from thrustmap.fitting.solve import solve

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
DEGREES = (0, 1, 2, 3)
DEFAULT_BLOCKS = 5
#: samples needed per polynomial coefficient for a degree to be a candidate
MIN_SAMPLES_PER_COEF = 10
#: battery-voltage span below which a γ slope cannot be told from noise and drift
MIN_SLOPE_SPAN_V = 0.5
#: a voltage bin with at least this many Df samples is populated: the corrected map may not be
#: worse than the uncorrected one there
MIN_BIN_SAMPLES = 20


@dataclass
class GammaFit:
    correction: GammaCorrection
    degree: int
    loss: str
    heldout: dict[int, float]  # degree -> held-out error (MAE for l1, RMSE for l2) of γ
    validation: str  # "leave-one-flight-out (k flights)" or "k contiguous time blocks"
    samples: int
    metrics: dict[str, Any] = field(default_factory=dict)
    heldout_se: dict[int, float] = field(default_factory=dict)  # standard error over folds
    warnings: list[str] = field(default_factory=list)
    # the no-worse check: per degree tried, the populated bins where the corrected map was
    # worse than the uncorrected one; ``corrected`` False when no γ(B) passed (γ = 1 kept)
    guard: dict[str, Any] = field(default_factory=dict)
    corrected: bool = True

    def to_dict(self) -> dict[str, Any]:
        return {
            "degree": self.degree,
            "loss": self.loss,
            "coefficients": list(self.correction.coefficients),
            "voltage_v": self.correction.voltage_v.to_list(),
            "heldout_error": {str(k): v for k, v in self.heldout.items()},
            "heldout_standard_error": {str(k): v for k, v in self.heldout_se.items()},
            "degree_rule": "one standard error over the held-out folds, among the degrees whose "
            f"corrected map is no worse than the uncorrected one in any voltage bin with "
            f"{MIN_BIN_SAMPLES}+ samples",
            "corrected": self.corrected,
            "no_worse_check": self.guard,
            "warnings": self.warnings,
            "validation": self.validation,
            "samples": self.samples,
            "metrics": self.metrics,
        }


# -- T_c in newtons ------------------------------------------------------------------------------


def thrust_command_n(
    table: pd.DataFrame, sidecar: dict[str, Any], tmap: ThrustMap | None, given: int | None = None
) -> tuple[FloatArray, str]:
    """T_c (collective N) from the Df, computing it through the map when the Df lacks it."""
    if "thrust_cmd_n" in table.columns and table["thrust_cmd_n"].notna().all():
        return table["thrust_cmd_n"].to_numpy(float), "Df column thrust_cmd_n"
    if tmap is None:
        raise ConfigError("this Df has no thrust_cmd_n column: give the stand map (--map)")
    volt = table["voltage_v"].to_numpy(float)
    rotors = _rotors(table, sidecar, given)
    motor_cols = sorted(c for c in table.columns if c.startswith("motor") and c.endswith("_pct"))
    scale_d = sidecar.get("columns", {}).get("motor_output_scale")
    if motor_cols and scale_d:
        mp, how = motor_pct_in_map_scale(
            table[motor_cols].to_numpy(float), ThrottleScale.from_dict(scale_d), tmap.throttle_scale
        )
        return thrust_from_motors(mp, volt, tmap, rotors), f"motor outputs through the map ({how})"
    if "thrust_cmd_norm" in table.columns:
        norm = table["thrust_cmd_norm"].to_numpy(float)
        t = rotors * tmap.thrust_n(norm * 100.0, volt, corrected=False)
        return np.asarray(t, float), "thrust_cmd_norm × 100 % of the map's scale, × rotors"
    raise DataFormatError("Df has no thrust command column (thrust_cmd_n, motor*_pct, norm)")


def _rotors(table: pd.DataFrame, sidecar: dict[str, Any], given: int | None = None) -> int:
    """The rotor count: the one the Df's logs recorded (``--rotors`` is for a Df without it,
    and one that contradicts it is refused: 6 given for a log of 4 motor outputs once kept
    γ = 1 with a warning, the map's thrust 50 % off)."""
    flights = sidecar.get("flights", {})
    counts = {int(v["rotors"]) for v in flights.values() if v.get("rotors")}
    if given is not None:
        if counts and given not in counts:
            raise ConfigError(
                f"--rotors {given}, but the Df's logs record "
                f"{' and '.join(str(c) for c in sorted(counts))} rotors (their motor outputs); "
                "--rotors is for a Df that does not record it"
            )
        return given
    if len(counts) == 1:
        return counts.pop()
    n = sum(1 for c in table.columns if c.startswith("motor") and c.endswith("_pct"))
    if n > 1:
        return n
    raise ConfigError("the rotor count is not recorded in the Df sidecar; give --rotors")


# -- fitting -------------------------------------------------------------------------------------


def _fit_poly(b: FloatArray, y: FloatArray, degree: int, loss: Loss) -> tuple[float, ...]:
    """Ascending raw-power coefficients, solved in a centred/scaled basis for conditioning."""
    bc = float(np.mean(b))
    bs = float(np.std(b)) or 1.0
    x = (b - bc) / bs
    design = np.vander(x, degree + 1, increasing=True)
    c = solve(design, y, loss=loss)
    poly = np.polynomial.Polynomial(c)(np.polynomial.Polynomial([-bc / bs, 1.0 / bs]))
    coef = np.zeros(degree + 1)
    coef[: len(poly.coef)] = poly.coef
    return tuple(float(v) for v in coef)


def _error(res: FloatArray, loss: str) -> float:
    return float(np.mean(np.abs(res))) if loss == "l1" else float(np.sqrt(np.mean(res**2)))


def _folds(groups: npt.NDArray[Any], time_s: FloatArray, blocks: int) -> tuple[list[Any], str]:
    names = list(dict.fromkeys(groups.tolist()))
    if len(names) >= 2:
        return [groups == g for g in names], f"leave-one-flight-out ({len(names)} flights)"
    order = np.argsort(time_s, kind="stable")
    masks = []
    for chunk in np.array_split(order, blocks):
        m = np.zeros(len(time_s), bool)
        m[chunk] = True
        masks.append(m)
    return masks, f"{blocks} contiguous time blocks of one flight"


def _check_pooling(side: dict[str, Any], allow_mixed: bool, warnings: list[str]) -> None:
    """Refuse to pool flights of different vehicles (mass or rotor count) unless asked."""
    flights = side.get("flights", {}) or {}
    masses = {k: v.get("mass_kg") for k, v in flights.items() if v.get("mass_kg") is not None}
    rotors = {k: v.get("rotors") for k, v in flights.items() if v.get("rotors") is not None}
    problems = []
    if len({round(float(m), 6) for m in masses.values()}) > 1:
        problems.append(
            "masses " + ", ".join(f"{k}: {float(m):g} kg" for k, m in sorted(masses.items()))
        )
    if len({int(r) for r in rotors.values()}) > 1:
        problems.append(
            "rotor counts " + ", ".join(f"{k}: {int(r)}" for k, r in sorted(rotors.items()))
        )
    if not problems:
        return
    text = "the Df mixes flights with different " + " and ".join(problems)
    if not allow_mixed:
        raise FitError(
            text + ": γ(B) of different vehicles need not agree; fit them separately, or pool "
            "them on purpose (--pool-mixed)"
        )
    warnings.append(text + " (pooled on request)")


@dataclass(frozen=True)
class _Samples:
    """The Df's usable samples: B (zeros without a voltage), γ = T_c / F_m, the flight or
    block each belongs to and its time, which rows of ``table`` (the Df's rows with a battery
    voltage) they are, and where T_c came from."""

    b: FloatArray
    gam: FloatArray
    groups: npt.NDArray[Any]
    time_s: FloatArray
    ok: npt.NDArray[np.bool_]
    t_cmd: FloatArray
    force: FloatArray
    volt: FloatArray
    no_voltage: bool
    t_src: str
    table: pd.DataFrame


@dataclass(frozen=True)
class GammaOptions:
    """How γ(B) is fitted: the loss, the degree (None: chosen by held-out error among
    ``degrees``), the time blocks of a one-flight Df's held-out folds and the voltage bins of
    its metrics."""

    loss: Loss = "l1"
    degree: int | None = None
    degrees: tuple[int, ...] = DEGREES
    blocks: int = DEFAULT_BLOCKS
    voltage_bins: int = 6

    def __post_init__(self) -> None:
        if self.loss not in ("l1", "l2"):
            raise ConfigError(f"unknown loss '{self.loss}'; expected l1 or l2")
        if self.degree is not None and self.degree not in DEGREES:
            raise ConfigError(f"γ degree must be one of {DEGREES}, got {self.degree}")


def fit_gamma(
    table: pd.DataFrame,
    sidecar: dict[str, Any] | None = None,
    tmap: ThrustMap | None = None,
    options: GammaOptions | None = None,
    *,
    rotors: int | None = None,
    allow_mixed: bool = False,
) -> GammaFit:
    """Fit γ(B) on a Df (one or more flights); ``options.degree=None`` chooses it by held-out
    error, among the degrees whose corrected map is no worse than the uncorrected one."""
    side = sidecar or {}
    opts = options or GammaOptions()
    loss, degree = opts.loss, opts.degree
    warnings: list[str] = []
    _check_pooling(side, allow_mixed, warnings)
    smp = _samples(table, side, tmap, rotors, degree, warnings)
    table = smp.table  # the rows with a battery voltage (all when the Df has none)
    candidates = _candidates(smp, degree, opts.degrees, warnings)
    masks, how = _folds(smp.groups, smp.time_s, opts.blocks)
    heldout, heldout_se = _heldout_errors(smp, candidates, masks, loss)
    vbox = Box(float(smp.b.min()), float(smp.b.max()))
    if smp.no_voltage:  # γ is constant: its voltage box only records where it may be applied
        vbox = tmap.validity.voltage_v if tmap is not None else Box(0.0, 0.0)
    if tmap is not None:
        rotors = _rotors(table, side, rotors)

    def metrics_of(corr: GammaCorrection) -> dict[str, Any]:
        return flight_metrics(
            table[smp.ok],
            side,
            None if smp.no_voltage else tmap,
            corr,
            smp.t_cmd[smp.ok],
            opts.voltage_bins,
            rotors,
        )

    # The no-worse check: each degree's corrected map against the uncorrected one, per
    # populated voltage bin (in the Table-4 metric the output shows).
    tried: dict[int, tuple[tuple[float, ...], dict[str, Any], list[dict[str, Any]]]] = {}
    for d in candidates:
        c = _fit_poly(smp.b, smp.gam, d, loss)
        mets = metrics_of(GammaCorrection(coefficients=c, voltage_v=vbox, loss=loss))
        tried[d] = (c, mets, worse_bins(mets))
    chosen, corrected, guard = _choose(tried, heldout, heldout_se, degree, warnings)
    for w in warnings:
        log.warning("γ fit: %s", w)
    if corrected or degree is not None:
        coef = tried[chosen][0]
    else:
        coef, chosen = (1.0,), 0  # the simpler choice: no correction
    guard["kept"] = f"degree {chosen}" if corrected or degree is not None else "γ = 1 (none)"
    correction = GammaCorrection(coefficients=coef, voltage_v=vbox, loss=loss)
    if tmap is not None and rotors:
        ok = smp.ok
        outside = map_extrapolation(
            tmap, smp.volt[ok], smp.force[ok] / rotors, "per-rotor thrust (F_m / rotors)"
        )
        for w in outside:
            log.warning("γ fit: %s", w)
        warnings.extend(outside)
    fit = GammaFit(correction, chosen, loss, heldout, how, int(smp.ok.sum()))
    fit.heldout_se = heldout_se
    fit.warnings = warnings
    fit.guard = guard
    fit.corrected = corrected or degree is not None
    fit.metrics = metrics_of(correction)
    fit.metrics["no_worse_check"] = guard
    if smp.no_voltage:
        fit.metrics["voltage_unknown"] = (
            "no battery voltage in the Df: γ fitted as a constant; e_Th (which needs B) not "
            "computed, no voltage bins"
        )
    fit.metrics["thrust_cmd_source"] = smp.t_src
    fit.correction = GammaCorrection(
        coefficients=coef,
        voltage_v=correction.voltage_v,
        loss=loss,
        metrics={"degree": chosen, "heldout_error": heldout, "validation": how, **fit.metrics},
    )
    return fit


def _samples(
    table: pd.DataFrame,
    side: dict[str, Any],
    tmap: ThrustMap | None,
    rotors: int | None,
    degree: int | None,
    warnings: list[str],
) -> _Samples:
    """The usable samples (T_c and F_m positive, B known unless the Df has none at all); at
    least 10, and a Df without voltage only with T_c in newtons and a constant γ."""
    table, no_voltage = _voltage_rows(table, warnings)
    if no_voltage and not ("thrust_cmd_n" in table.columns and table["thrust_cmd_n"].notna().all()):
        raise FitError(
            "the Df has no battery voltage and no thrust_cmd_n: T_c would have to come through "
            "the stand map's forward direction, which needs B"
        )
    if no_voltage and degree is not None and degree > 0:
        raise ConfigError(f"the Df has no battery voltage: a degree-{degree} γ(B) needs B")
    t_cmd, t_src = thrust_command_n(table, side, tmap, rotors)
    force = table["force_n"].to_numpy(float)
    volt = table["voltage_v"].to_numpy(float)
    ok = np.isfinite(t_cmd) & np.isfinite(force) & (force > 0) & (t_cmd > 0)
    if not no_voltage:
        ok &= np.isfinite(volt)
    if ok.sum() < 10:
        raise FitError(f"only {int(ok.sum())} usable Df samples; need at least 10")
    b, gam = volt[ok], t_cmd[ok] / force[ok]
    groups = table["flight"].to_numpy()[ok] if "flight" in table.columns else np.zeros(ok.sum())
    time_s = np.asarray(
        table["time_s"].to_numpy(float)[ok] if "time_s" in table.columns else np.arange(len(b)),
        dtype=np.float64,
    )
    if no_voltage:
        b = np.zeros(len(b))  # a constant γ does not depend on B; the zeros only feed the solver
    return _Samples(b, gam, groups, time_s, ok, t_cmd, force, volt, no_voltage, t_src, table)


def _candidates(
    smp: _Samples, degree: int | None, degrees: tuple[int, ...], warnings: list[str]
) -> list[int]:
    """The degrees to try: the one asked for, else those the samples can support (enough
    samples per coefficient; a slope only over a voltage span that can show one)."""
    n = len(smp.b)
    span = float(np.ptp(smp.volt[smp.ok])) if not smp.no_voltage else 0.0
    candidates = [degree] if degree is not None else list(degrees)
    if smp.no_voltage:
        return [0]
    if degree is None:
        few = [d for d in candidates if n < MIN_SAMPLES_PER_COEF * (d + 1)]
        if few and len(few) < len(candidates):
            warnings.append(
                f"{n} samples: degree {', '.join(map(str, few))} not tried (needs "
                f"{MIN_SAMPLES_PER_COEF} samples per coefficient)"
            )
        candidates = [d for d in candidates if d not in few] or [0]
        if span < MIN_SLOPE_SPAN_V and any(d > 0 for d in candidates):
            warnings.append(
                f"battery voltage spans only {span:.2f} V (< {MIN_SLOPE_SPAN_V:g} V): a slope of "
                "γ in B cannot be told from noise; fitted a constant γ (fly the battery down "
                "further, or pool flights at other voltages)"
            )
            candidates = [0]
    elif degree > 0 and span < MIN_SLOPE_SPAN_V:
        warnings.append(
            f"battery voltage spans only {span:.2f} V (< {MIN_SLOPE_SPAN_V:g} V): the requested "
            f"degree-{degree} γ(B) is not supported by the data"
        )
    return candidates


def _heldout_errors(
    smp: _Samples, candidates: list[int], masks: list[npt.NDArray[np.bool_]], loss: Loss
) -> tuple[dict[int, float], dict[int, float]]:
    """Each degree's held-out error of γ over the folds, and its standard error."""
    b, gam = smp.b, smp.gam
    heldout: dict[int, float] = {}
    heldout_se: dict[int, float] = {}
    for d in candidates:
        res = np.full(len(b), np.nan)
        per_fold: list[float] = []
        for test in masks:
            train = ~test
            if train.sum() < d + 2 or not test.any():
                continue
            coef = _fit_poly(b[train], gam[train], d, loss)
            box = Box(float(b[train].min()), float(b[train].max()))
            res[test] = gam[test] - GammaCorrection(coef, box).gamma(b[test])
            per_fold.append(_error(res[test], loss))
        heldout[d] = _error(res[np.isfinite(res)], loss) if np.isfinite(res).any() else np.inf
        k = len(per_fold)
        heldout_se[d] = float(np.std(per_fold, ddof=1) / np.sqrt(k)) if k >= 2 else np.inf
    return heldout, heldout_se


def _choose(
    tried: dict[int, tuple[tuple[float, ...], dict[str, Any], list[dict[str, Any]]]],
    heldout: dict[int, float],
    heldout_se: dict[int, float],
    degree: int | None,
    warnings: list[str],
) -> tuple[int, bool, dict[str, Any]]:
    """The degree kept (one standard error over the folds among those no worse than the
    uncorrected map in any populated bin), whether it corrects at all, and the no-worse
    check's record."""
    if degree is None:
        by_heldout = _one_se(heldout, heldout_se, list(heldout))
        passing = [d for d in heldout if not tried[d][2]]
        chosen = _one_se(heldout, heldout_se, passing) if passing else by_heldout
    else:
        chosen = by_heldout = degree
    corrected = not tried[chosen][2]
    guard: dict[str, Any] = {
        "min_bin_samples": MIN_BIN_SAMPLES,
        "metric": tried[chosen][2][0]["metric"] if tried[chosen][2] else _guard_metric(tried),
        "rejected": [
            {
                "degree": d,
                "worse": w,
                "by_voltage_after": [_after_of(row) for row in tried[d][1].get("by_voltage", [])],
            }
            for d, (_, _, w) in sorted(tried.items())
            if w
        ],
    }
    if degree is None and chosen != by_heldout:
        warnings.append(
            f"degree {by_heldout} (the held-out choice) not used: {_worse_text(tried[by_heldout][2])}; "
            f"kept degree {chosen}, which is no worse in any bin with {MIN_BIN_SAMPLES}+ samples"
        )
    if not corrected:
        if degree is None:
            warnings.append(
                "no γ(B) of degree "
                + ", ".join(map(str, sorted(tried)))
                + " keeps the corrected map no worse than the uncorrected one in every voltage "
                f"bin with {MIN_BIN_SAMPLES}+ samples ({_worse_text(tried[chosen][2])}): "
                "kept the uncorrected map (γ = 1)"
            )
        else:
            warnings.append(
                f"the requested degree-{degree} γ(B) makes the map worse than uncorrected: "
                f"{_worse_text(tried[chosen][2])}"
            )
    return chosen, corrected, guard


def _one_se(heldout: dict[int, float], se: dict[int, float], among: list[int]) -> int:
    """The simplest degree among ``among`` whose held-out error is within one standard error
    of the best of them."""
    best = min(among, key=lambda d: heldout[d])
    limit = heldout[best] + (se[best] if np.isfinite(se.get(best, np.inf)) else 0.0)
    return min(d for d in among if heldout[d] <= limit)


def _metric_key(row: dict[str, Any]) -> str:
    """The Table-4 error the no-worse check reads: e_Th (the map's throttle) when the fit had
    the map, else e_T (thrust, % of F_m)."""
    return "e_Th" if "e_Th_before_pct" in row else "e_T"


def _after_of(row: dict[str, Any]) -> float:
    return float(row[f"{_metric_key(row)}_after_pct"]["mean"])


def _guard_metric(tried: dict[int, Any]) -> str:
    for _, mets, _ in tried.values():
        for row in mets.get("by_voltage", []):
            return _metric_key(row)
    return "e_Th"


def worse_bins(metrics: dict[str, Any], min_samples: int = MIN_BIN_SAMPLES) -> list[dict[str, Any]]:
    """Populated voltage bins (``min_samples``+) where the corrected map's mean error is above
    the uncorrected one's."""
    out = []
    for row in metrics.get("by_voltage", []):
        if row["samples"] < min_samples:
            continue
        key = _metric_key(row)
        before = float(row[f"{key}_before_pct"]["mean"])
        after = float(row[f"{key}_after_pct"]["mean"])
        if after > before:
            out.append(
                {
                    "voltage_v": list(row["voltage_v"]),
                    "samples": int(row["samples"]),
                    "metric": key,
                    "before_pct": before,
                    "after_pct": after,
                }
            )
    return out


def _worse_text(worse: list[dict[str, Any]]) -> str:
    """'worse at 11.04..11.22 V (53 samples): e_Th 1.449 → 1.569 %; ...'."""
    return "corrected map worse than uncorrected at " + "; ".join(
        f"{w['voltage_v'][0]:.2f}..{w['voltage_v'][1]:.2f} V ({w['samples']} samples): "
        f"{w['metric']} {w['before_pct']:.3f} → {w['after_pct']:.3f} %"
        for w in worse
    )


def _voltage_rows(table: pd.DataFrame, warnings: list[str]) -> tuple[pd.DataFrame, bool]:
    """The Df rows with a battery voltage, and whether the Df has none at all (then every row is
    kept and γ can only be a constant). Rows lacking a voltage among others are dropped."""
    volt = pd.to_numeric(table["voltage_v"], errors="coerce").to_numpy(float)
    known = np.isfinite(volt) & (volt > 0)
    if len(table) and not known.any():
        text = (
            "the Df has no battery voltage (the log had none): γ fitted as a constant (degree 0); "
            "a slope of γ in B cannot be fitted without B"
        )
        warnings.append(text)
        return table, True
    if not known.all():
        text = f"{int((~known).sum())} of {len(table)} Df samples have no battery voltage: dropped"
        warnings.append(text)
        return table[known].reset_index(drop=True), False
    return table, False


# -- Table-4 metrics -----------------------------------------------------------------------------


def _ms(x: FloatArray) -> dict[str, float]:
    return {"mean": float(np.mean(x)), "std": float(np.std(x))} if len(x) else {}


def flight_metrics(
    table: pd.DataFrame,
    sidecar: dict[str, Any],
    tmap: ThrustMap | None,
    correction: GammaCorrection,
    t_cmd: FloatArray,
    voltage_bins: int = 6,
    rotors: int | None = None,
) -> dict[str, Any]:
    """e_Th and e_T before/after γ, mean ± std, overall and per voltage bin."""
    force = table["force_n"].to_numpy(float)
    volt = table["voltage_v"].to_numpy(float)
    if len(correction.coefficients) == 1:  # a constant γ needs no B (a Df may have none)
        g = np.full(len(volt), correction.coefficients[0])
    else:
        g = correction.gamma(volt)
    per: dict[str, FloatArray] = {
        "e_T_before_n": np.abs(t_cmd - force),
        "e_T_after_n": np.abs(t_cmd / g - force),
    }
    per["e_T_before_pct"] = per["e_T_before_n"] / force * 100.0
    per["e_T_after_pct"] = per["e_T_after_n"] / force * 100.0
    th_src = None
    if tmap is not None:
        if rotors is None:
            raise ConfigError("Table-4 throttle errors need the rotor count; give --rotors")
        f_rotor = force / rotors
        th_note = str(sidecar.get("columns", {}).get("throttle_pct", ""))
        if "throttle_pct" in table.columns and "map's scale" in th_note:
            th_sent = table["throttle_pct"].to_numpy(float)
            th_src = "mean motor output (map's scale)"
        else:
            th_sent = tmap.throttle_pct(t_cmd / rotors, volt, corrected=False)
            th_src = "f̂(T_c/n, B): the uncorrected map's throttle for the command"
        before = tmap.throttle_pct(f_rotor, volt, corrected=False)
        after = tmap.with_correction(correction).throttle_pct(f_rotor, volt)
        per["e_Th_before_pct"] = np.abs(th_sent - before)
        per["e_Th_after_pct"] = np.abs(th_sent - after)
    out: dict[str, Any] = {k: _ms(v) for k, v in per.items()}
    out["throttle_sent"] = th_src
    out["e_T_pct_of"] = "F_m (measured collective force)"
    if not np.isfinite(volt).all():  # no battery voltage: no voltage bins
        out["by_voltage"] = []
        return out
    edges = np.linspace(float(volt.min()), float(volt.max()), voltage_bins + 1)
    bins = []
    idx = np.clip(np.digitize(volt, edges[1:-1]), 0, voltage_bins - 1)
    for k in range(voltage_bins):
        m = idx == k
        if not m.any():
            continue
        row: dict[str, Any] = {
            "voltage_v": [float(edges[k]), float(edges[k + 1])],
            "samples": int(m.sum()),
            "gamma": _ms(t_cmd[m] / force[m]),
        }
        for key, v in per.items():
            row[key] = _ms(v[m])
        bins.append(row)
    out["by_voltage"] = bins
    return out


def physical_refusals(fit: GammaFit) -> list[str]:
    """Why this γ(B) should not be written (empty: it may): a Df shorter than a γ fit needs
    (``MIN_DF_SAMPLES``, the length ``flightlog extract`` calls too short), or a γ outside the
    physical band (``core.physical.GAMMA_BAND``) anywhere over the flown voltages."""
    out = []
    if fit.samples < MIN_DF_SAMPLES:
        out.append(
            f"only {fit.samples} Df samples (fewer than {MIN_DF_SAMPLES}): too short for a γ fit"
        )
    v = fit.correction.voltage_v
    band = gamma_outside_band(fit.correction.gamma(np.linspace(v.lo, v.hi, 25)).tolist())
    if band is not None:
        out.append(band)
    return out


def check_physical(fit: GammaFit, *, force: bool = False) -> list[str]:
    """Refuse (``FitError``) a γ(B) with :func:`physical_refusals`, unless ``force``: then the
    reasons are returned (and logged) for the map to record."""
    reasons = physical_refusals(fit)
    if reasons and not force:
        raise FitError("; ".join(reasons) + "; nothing written (--force writes it anyway)")
    for reason in reasons:
        log.warning("forced (--force), recorded in the map: %s", reason)
    return reasons


def corrected_map(
    tmap: ThrustMap, fit: GammaFit, sources: list[dict[str, Any]], *, forced: Sequence[str] = ()
) -> ThrustMap:
    """The stand map with the γ correction block attached (predict applies f̂(γ(B)·T_c, B));
    ``forced``: the refusals the user overrode with ``--force``, recorded in the block."""
    metrics = dict(fit.correction.metrics)
    if forced:
        metrics["forced"] = list(forced)
    corr = GammaCorrection(
        coefficients=fit.correction.coefficients,
        voltage_v=fit.correction.voltage_v,
        loss=fit.loss,
        metrics=metrics,
        sources=tuple(sources),
    )
    return tmap.with_correction(corr)
