"""The rotor at rest: which samples had it stopped (tare information, not map points), and
the load cell's zero measured on the rest plateau."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from thrustmap.fitting.dataset import STEP_SUMMARY, Dataset, FloatArray
from thrustmap.fitting.selection.options import Selection


def th_pct_le(ds: Dataset, th: FloatArray, sel: Selection) -> npt.NDArray[np.bool_]:
    """Points at the zero command (within the plateau tolerance)."""
    return np.asarray(ds.throttle_scale.to_pct(th) <= sel.plateau_tolerance_pct, dtype=bool)


#: the rest plateau's mean is the load cell's zero when it is this many standard errors from 0
ZERO_SIGMAS = 3.0


def rest_zero(ds: Dataset, sel: Selection) -> float | None:
    """The load cell's zero offset measured on the file's rest plateau, or None.

    Samples at the zero command with the rotor stopped read no thrust, so their median is the
    offset every reading of the file carries (a stand tared off-zero, a cell that drifted before
    the sweep). Taken only when it is measured: at least ``min_plateau_samples`` independent rest
    readings (a sample-and-hold load cell's repeats are one reading), and a median beyond
    ``ZERO_SIGMAS`` standard errors of their noise. A step summary's single
    averaged rest row (the stand software tared before the test) has no noise to judge it by
    and is not used."""
    if ds.meta.get("layout") == STEP_SUMMARY:
        return None
    rest = rotor_stopped(ds, sel) & (ds.throttle_pct <= sel.plateau_tolerance_pct)
    rest &= np.isfinite(ds.thrust_n)
    if not rest.any():
        return None
    # the rest plateau: samples held at one command (not a command passing below the scale)
    level = float(np.median(ds.throttle_pct[rest]))
    rest &= np.abs(ds.throttle_pct - level) <= sel.plateau_tolerance_pct
    t = ds.thrust_n[rest]
    # independent readings: a load cell that holds its value between updates repeats it, so
    # the readings are the changes of value, not the samples
    readings = 1 + int(np.count_nonzero(np.diff(t))) if len(t) else 0
    if readings < sel.min_plateau_samples:
        return None
    zero = float(np.median(t))
    err = float(np.std(t)) / np.sqrt(readings)
    return zero if abs(zero) > ZERO_SIGMAS * err and zero != 0.0 else None


#: a row reading rpm 0 still turns when its thrust stands this share of the file's thrust range
#: above the rest reading (the spin-up measurement's floor, spinup.FLOOR_FRACTION)
MAKING_THRUST_FRACTION = 0.01


def rotor_stopped(ds: Dataset, sel: Selection) -> npt.NDArray[np.bool_]:
    """Samples with the rotor stopped: a command at the bottom of the scale (within the plateau
    tolerance), or, where the log has rpm that rises above 1000, rpm under 1 % of its maximum
    while the load cell shows no thrust. Their thrust is the load cell's offset, not a point of
    the map. An rpm probe reads 0 below its lowest speed (the RCbenchmark stand's electrical rpm
    at 1050 µs on 2S: 0 rpm, yet 6 gf and 0.38 A against 0.1 A at rest): a row making thrust
    above the rest reading by ``MAKING_THRUST_FRACTION`` of the file's range is turning, as the
    spin-up measurement counts it (thrust OR rpm)."""
    at_bottom = ds.throttle_pct <= sel.plateau_tolerance_pct
    stopped = at_bottom
    if ds.rpm is not None and np.isfinite(ds.rpm).any():
        top = float(np.nanmax(ds.rpm))
        if top > 1000.0:
            no_rpm = np.nan_to_num(ds.rpm, nan=np.inf) < 0.01 * top
            t = ds.thrust_n
            fin = np.isfinite(t)
            rest = at_bottom & fin
            base = float(np.median(t[rest])) if rest.any() else 0.0  # else the stand's tare
            full = float(np.percentile(t[fin], 99)) - base if fin.any() else 0.0
            making = fin & (t - base > MAKING_THRUST_FRACTION * full)
            if not full > 0:
                making[:] = False
            # a zero command with the rotor still turning and pulling (a stand's ramped stop,
            # the spin-down after a stop) is not rest: its thrust is not the load cell's zero
            stopped = (stopped & ~(~no_rpm & making)) | (no_rpm & ~making)
    return np.asarray(stopped, dtype=bool)
