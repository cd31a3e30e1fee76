"""One timeline for every stream: bin means, running statistics, masks of runs, and the
time sanity that keeps a corrupt timestamp from making the timeline span weeks."""

from __future__ import annotations

import warnings as _warnings

import numpy as np

from thrustmap.core.errors import DataFormatError
from thrustmap.fitting.df.options import BoolArray
from thrustmap.flightlogs.series import FloatArray, Signal, nanmedian

# -- resampling ----------------------------------------------------------------------------------


def bin_mean(sig: Signal, t0: float, rate_hz: float, nbins: int, max_gap_s: float) -> FloatArray:
    """Mean of the samples in each bin; bins without samples interpolate when data is near."""
    centres = t0 + (np.arange(nbins) + 0.5) / rate_hz
    vals = sig.values if sig.values.ndim == 2 else sig.values[:, None]
    out = np.full((nbins, vals.shape[1]), np.nan)
    b = np.floor((sig.time_s - t0) * rate_hz).astype(np.int64)
    inside = (b >= 0) & (b < nbins)
    for k in range(vals.shape[1]):
        v = vals[:, k]
        ok = inside & np.isfinite(v)
        cnt = np.bincount(b[ok], minlength=nbins)
        tot = np.bincount(b[ok], weights=v[ok], minlength=nbins)
        col = np.where(cnt > 0, tot / np.maximum(cnt, 1), np.nan)
        fin = np.isfinite(v)
        if fin.sum() >= 1:
            ts, vs = sig.time_s[fin], v[fin]
            if len(ts) == 1:  # one sample: its distance to every bin centre
                near = np.abs(ts[0] - centres)
            else:
                idx = np.clip(np.searchsorted(ts, centres), 1, len(ts) - 1)
                near = np.minimum(np.abs(ts[idx] - centres), np.abs(ts[idx - 1] - centres))
            interp = np.interp(centres, ts, vs)
            col = np.where(np.isnan(col) & (near <= max_gap_s), interp, col)
        out[:, k] = col
    return out if sig.values.ndim == 2 else out[:, 0]


def _windows(x: FloatArray, window: int) -> FloatArray:
    """Centred windows of ``window`` bins (NaN beyond the ends), one row per bin; the same
    alignment as pandas' ``rolling(window, center=True)``."""
    before = window // 2
    padded = np.concatenate([np.full(before, np.nan), x, np.full(window - 1 - before, np.nan)])
    return np.lib.stride_tricks.sliding_window_view(padded, window)


def _running_median(x: FloatArray, window: int) -> FloatArray:
    """Centred running median over ``window`` bins, NaN-aware (NaN only where all are)."""
    window = max(window, 1)
    if window == 1:
        return np.asarray(x, float)
    out = np.full(len(x), np.nan)
    views = _windows(np.asarray(x, float), window)  # a view: no copy
    step = max(1, 2_000_000 // window)  # nanmedian copies: bounded chunks
    with _warnings.catch_warnings():
        _warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN windows stay NaN
        for a in range(0, len(x), step):
            out[a : a + step] = nanmedian(views[a : a + step], axis=1)
    return out


def steady_mask(cmd: FloatArray, window: int, tol: float) -> BoolArray:
    """True where the command is within ``tol`` (relative) of its centred running median."""
    med = _running_median(np.asarray(cmd, float), window)
    with np.errstate(invalid="ignore"):
        return np.asarray(np.abs(cmd - med) <= tol * np.abs(med))


def running_mean(x: FloatArray, window: int) -> FloatArray:
    """Centred running mean (NaN-aware) over ``window`` bins."""
    if window <= 1:
        return x
    before = window // 2
    fin = np.isfinite(x)
    v = np.concatenate([[0.0], np.cumsum(np.where(fin, x, 0.0))])
    c = np.concatenate([[0], np.cumsum(fin.astype(np.int64))])
    idx = np.arange(len(x))
    lo = np.clip(idx - before, 0, len(x))
    hi = np.clip(idx - before + window, 0, len(x))
    n = c[hi] - c[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.asarray(np.where(n > 0, (v[hi] - v[lo]) / np.maximum(n, 1), np.nan), float)


def mask_runs(mask: BoolArray) -> list[tuple[int, int]]:
    """[start, stop) index ranges where mask is True."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=True))


def long_runs(mask: BoolArray, min_len: int) -> BoolArray:
    """``mask`` with its True runs shorter than ``min_len`` bins cleared."""
    out = np.zeros(len(mask), bool)
    for a, b in mask_runs(mask):
        if b - a >= min_len:
            out[a:b] = True
    return out


def dilate(mask: BoolArray, radius: int) -> BoolArray:
    """True within ``radius`` bins of a True bin."""
    if radius <= 0 or not mask.any():
        return mask
    c = np.concatenate([[0], np.cumsum(mask.astype(np.int64))])
    n = len(mask)
    idx = np.arange(n)
    lo = np.clip(idx - radius, 0, n)
    hi = np.clip(idx + radius + 1, 0, n)
    return np.asarray((c[hi] - c[lo]) > 0)


# -- time sanity ---------------------------------------------------------------------------------

#: a pause in the log longer than this splits it into stretches (logging stopped, a new flight)
TIME_JUMP_S = 60.0
#: the resampled timeline may hold at most this many bins per accelerometer sample (plus a
#: constant): a span the samples cannot fill is a corrupt or mistyped time, not a flight
BINS_PER_SAMPLE = 4
BINS_SLACK = 36_000


def plausible_timeline(acc: Signal, rate_hz: float, path: str) -> tuple[Signal, list[str]]:
    """The accelerometer samples whose times are plausible, and warnings for those dropped.

    One mistyped or bit-flipped time (``3005000`` among 0..300 s) would otherwise make the
    resampled timeline span weeks: gigabytes of empty bins. Samples with non-finite times, and
    stretches (separated by more than TIME_JUMP_S) too small to be flying (fewer than 5 samples
    or 0.1 % of the log), are dropped with a warning; if the remaining span still needs far more
    bins than there are samples, the log's times are refused. Memory stays bounded by the input.
    """
    t = acc.time_s
    warnings: list[str] = []
    keep = np.isfinite(t)
    if not keep.all():
        warnings.append(f"{int((~keep).sum())} accelerometer samples without a valid time dropped")
    t_ok = t[keep]
    if not len(t_ok):
        raise DataFormatError("no accelerometer sample has a valid time", file=path)
    order_ok = bool(np.all(np.diff(t_ok) >= 0))
    if not order_ok:
        raise DataFormatError(
            "accelerometer times go backwards; expected increasing timestamps", file=path
        )
    breaks = np.flatnonzero(np.diff(t_ok) > TIME_JUMP_S) + 1
    bounds = [0, *breaks.tolist(), len(t_ok)]
    minimum = max(5, len(t_ok) // 1000)
    idx_ok = np.flatnonzero(keep)
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        if b - a < minimum and len(bounds) > 2:
            keep[idx_ok[a:b]] = False
            warnings.append(
                f"{b - a} sample(s) at t = {t_ok[a]:.6g} s dropped: isolated by a time jump of "
                f"more than {TIME_JUMP_S:g} s from the rest of the log (a corrupt or mistyped time?)"
            )
    if not keep.any():
        raise DataFormatError("no accelerometer samples left after dropping time jumps", file=path)
    kept_t = t[keep]
    span_s = float(kept_t[-1] - kept_t[0])
    max_bins = BINS_PER_SAMPLE * len(kept_t) + BINS_SLACK
    if span_s * rate_hz > max_bins:
        raise DataFormatError(
            f"the log's times span {span_s:.6g} s for only {len(kept_t)} accelerometer samples; "
            "expected a flight's timestamps (a corrupt or mistyped time?)",
            file=path,
        )
    if keep.all():
        return acc, warnings
    return Signal(t[keep], acc.values[keep], acc.unit, acc.origin), warnings
