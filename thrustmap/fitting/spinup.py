"""The lowest command at which the stand saw the motor spin and make thrust reliably.

A firmware's idle and minimum-spin settings (ArduPilot MOT_SPIN_MIN, Betaflight's motor idle)
must sit where the motor really turns, not where a fitted curve reaches zero thrust: below that
point a real motor stalls or desyncs. This module reads it from the raw stand samples.

Per file (a sweep):
- a sample spins when its thrust, or its rpm where the file logs rpm, is above the stand's
  noise measured on the rest samples (the file's lowest command, within ``REST_BAND_PCT``):
  rest mean + max(``NOISE_SIGMAS`` x rest sd, ``FLOOR_FRACTION`` of the signal's full range),
  so a rest level with few samples is not trusted to be noiseless (thrust OR rpm: an rpm probe
  that drops out at high speed does not hide a motor making thrust);
- in command order, each sample takes the majority of ``MIN_RUN`` neighbours (not for a step
  summary, one row per step), so a lone row logged while the command changed neither confirms
  nor denies spinning;
- the file's spin-up command is the lowest from which every command above spins.
Over several files the answer is the highest of them: the motor spins there in every sweep.

The data cannot tell (``throttle_pct`` None, with the reason) when a thrust-only file has no
rest samples at the stop command, when the lowest command already spins (rpm), or when the
highest commands do not spin.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from thrustmap.fitting.dataset import Dataset, FloatArray, IntArray
from thrustmap.fitting.loaders.checks import is_step_summary

log = logging.getLogger(__name__)

REST_BAND_PCT = 0.5
#: thrust-only files: the rest level must be the stop command (within this of the scale's low
#: end), or the lowest logged command may already be spinning and nothing tells it apart
STOP_BAND_PCT = 1.0
NOISE_SIGMAS = 5.0
FLOOR_FRACTION = 0.01
MIN_RUN = 3
#: beyond this many rest-to-rest runs in one file, the file is taken as one sweep (bounded work)
MAX_SWEEPS = 500


@dataclass(frozen=True)
class SpinUp:
    """The measured lowest reliably spinning command, in % of the map's native scale."""

    throttle_pct: float | None
    signal: str  # "rpm", "thrust", or "rpm+thrust" over several files; "" when unknown
    reason: str
    per_file: tuple[dict[str, Any], ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return {
            "throttle_pct": self.throttle_pct,
            "signal": self.signal,
            "reason": self.reason,
            "method": (
                f"lowest command from which every command shows thrust or rpm above rest mean + "
                f"max({NOISE_SIGMAS:g} sd, {FLOOR_FRACTION:g} x full range) (majority of "
                f"{MIN_RUN} neighbours); highest over files"
            ),
            "per_file": list(self.per_file),
        }

    @classmethod
    def from_dict(cls, data: Any) -> SpinUp | None:
        """None when ``data`` is not a spin-up block this tool wrote (then it is ignored)."""
        if not isinstance(data, dict):
            return None
        value = data.get("throttle_pct")
        if value is not None and not (
            isinstance(value, (int, float)) and math.isfinite(value) and -5.0 <= value <= 105.0
        ):
            return None
        per_file = data.get("per_file", [])
        return cls(
            None if value is None else float(value),
            str(data.get("signal", "")),
            str(data.get("reason", "")),
            tuple(p for p in per_file if isinstance(p, dict)) if isinstance(per_file, list) else (),
        )


def _threshold(sig: FloatArray, n_rest: int) -> float | None:
    """Noise threshold of a signal whose first ``n_rest`` samples are at rest (None when it
    never rises above its rest level)."""
    rest = sig[:n_rest]
    base = float(np.mean(rest))
    full = float(np.percentile(sig, 99)) - base
    if not full > 0:
        return None
    return base + max(NOISE_SIGMAS * float(np.std(rest)), FLOOR_FRACTION * full)


def file_spin_up(ds: Dataset) -> dict[str, Any]:
    """One file's spin-up (``throttle_pct`` None with a ``reason`` when it cannot tell)."""
    out: dict[str, Any] = {"file": ds.name, "throttle_pct": None}
    pct = np.asarray(ds.throttle_pct, dtype=float)
    thrust = np.asarray(ds.thrust_n, dtype=float)
    rpm = None if ds.rpm is None else np.asarray(ds.rpm, dtype=float)
    ok = np.isfinite(pct) & np.isfinite(thrust)
    if rpm is not None:
        ok &= np.isfinite(rpm)
        if not np.any(rpm[ok] > 0):
            rpm = None  # an rpm column that never reads: not logged
    out["signal"] = "thrust" if rpm is None else "rpm+thrust"
    if int(ok.sum()) < 2:
        out["reason"] = "fewer than two samples"
        return out
    pct, thrust = pct[ok], thrust[ok]
    low = float(pct.min())
    rest = pct <= low + REST_BAND_PCT
    if rpm is None and low > STOP_BAND_PCT:
        out["reason"] = (
            f"no rpm logged and no sample at the stop command (lowest {low:.3g} %): "
            "cannot tell whether it already spins"
        )
        return out
    if rpm is not None:
        rpm = rpm[ok]
        if float(np.median(rpm[rest])) > 0:
            out["reason"] = f"the lowest command ({low:.3g} %) already spins"
            return out
    native = ds.throttle_native[ok]
    times = None if ds.time_s is None else ds.time_s[ok]
    summary = is_step_summary(native, times, ds.throttle_scale)
    sweeps = _sweeps(rest)
    if not summary:  # a run of one or two rows is a command passing by, not a sweep
        sweeps = [(r, i) for r, i in sweeps if len(i) >= MIN_RUN]
    if len(sweeps) > MAX_SWEEPS:  # the command dithers across the rest band: one sweep
        above = np.flatnonzero(~rest)
        sweeps = [(np.flatnonzero(rest), above)]
        out["note"] = f"more than {MAX_SWEEPS} sweeps: taken as one"
    if not sweeps:
        out["reason"] = "no sample above the rest command"
        return out
    values: list[float] = []
    for rest_idx, idx in sweeps:
        v = _sweep_spin(pct, thrust, rpm, rest_idx, idx, summary)
        if v is not None:
            values.append(v)
    out.update(sweeps=len(sweeps), sweeps_spinning=len(values))
    if not values:
        out["reason"] = "no sweep shows thrust or rpm above the stand's noise at its top"
        return out
    value = max(values)
    out["throttle_pct"] = value
    out["reason"] = (
        f"thrust or rpm above rest + noise at every command from {value:.3f} % up "
        f"({len(values)} of {len(sweeps)} sweep(s) reach spinning)"
    )
    return out


def _sweeps(rest: npt.NDArray[np.bool_]) -> list[tuple[IntArray, IntArray]]:
    """(rest samples before it, samples of it) for each run of samples above rest, in file
    order; a sweep with no rest before it takes the rest run after it."""
    idx = np.arange(len(rest))
    edges = np.flatnonzero(np.diff(rest.astype(int)) != 0) + 1
    runs = np.split(idx, edges)
    out: list[tuple[IntArray, IntArray]] = []
    for k, run in enumerate(runs):
        if rest[run[0]]:
            continue
        before = runs[k - 1] if k > 0 else None
        after = runs[k + 1] if k + 1 < len(runs) else None
        base = before if before is not None else after
        if base is not None:
            out.append((base, run))
    return out


def _sweep_spin(
    pct: FloatArray,
    thrust: FloatArray,
    rpm: FloatArray | None,
    rest_idx: IntArray,
    idx: IntArray,
    summary: bool,
) -> float | None:
    """Lowest command of one sweep from which every command spins (None: it never does)."""
    spinning = np.zeros(len(idx), dtype=bool)
    for sig in (thrust, rpm):
        if sig is None:
            continue
        lvl = _threshold(np.concatenate([sig[rest_idx], sig[idx]]), len(rest_idx))
        if lvl is not None:
            spinning |= sig[idx] > lvl
    order = np.argsort(pct[idx], kind="stable")
    cmd, flag = pct[idx][order], spinning[order]
    if not summary and len(flag) >= MIN_RUN:
        # majority of MIN_RUN neighbours in command order: a lone row logged while the command
        # changed (or a sensor glitch) neither confirms nor denies spinning
        padded = np.concatenate([flag[:1], flag, flag[-1:]]).astype(int)
        flag = np.convolve(padded, np.ones(MIN_RUN, dtype=int), mode="valid") * 2 > MIN_RUN
    if not flag[-1]:
        return None
    still = np.flatnonzero(~flag)
    return float(cmd[0 if not len(still) else int(still[-1]) + 1])


def spin_up(datasets: Sequence[Dataset]) -> SpinUp:
    """The lowest command spinning in every file that can tell (the highest of their answers)."""
    files = tuple(file_spin_up(d) for d in datasets)
    told = [f for f in files if f["throttle_pct"] is not None]
    if not told:
        why = "; ".join(f"{f['file']}: {f.get('reason', '')}" for f in files)
        return SpinUp(None, "", f"the stand data cannot tell ({why})", files)
    worst = max(told, key=lambda f: float(f["throttle_pct"]))
    kinds = sorted({str(f["signal"]) for f in told})
    untold = len(files) - len(told)
    reason = f"highest over {len(told)} file(s) ({worst['file']}: {worst['reason']})" + (
        f"; {untold} file(s) could not tell" if untold else ""
    )
    value = float(worst["throttle_pct"])
    log.info("spin-up: %.3f %% of the throttle scale (%s)", value, reason)
    return SpinUp(value, " or ".join(kinds), reason, files)
