"""How far a map fitted on a simulated stand's log lies from the simulator's truth.

Test and benchmark support only. ``fit_error_vs_truth`` fits the log as ``thrustmap fit`` does
and scores |map − truth| (% throttle) at the log's steady points (every point but the motor at
rest), the truth being the plant's own throttle for that thrust and voltage."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
#: the plant's throttle fraction -> % of the log's own throttle scale
ToPct = Callable[[FloatArray], FloatArray]


def percent_of_scale(fraction: FloatArray) -> FloatArray:
    """The plant's throttle fraction as % of the log's scale (µs 1000..2000, a duty, a %)."""
    return fraction * 100.0


def einsz_label(fraction: FloatArray) -> FloatArray:
    """einsz/whoop_thrust_stand's percent, a label of DShot ``map(pct, 1, 100, 1, 2000)``."""
    return 1.0 + (fraction * 2000.0 - 1.0) * 99.0 / 1999.0


def fit_error_vs_truth(
    csv: Path,
    plant: str,
    to_pct: ToPct = percent_of_scale,
) -> tuple[float, float, int]:
    """Mean and max |map − truth| (% throttle) at the log's steady points, and their count."""
    from thrustmap.fitting.fit.fitmap import fit_map
    from thrustmap.fitting.loaders.load import load_dataset
    from thrustmap.fitting.selection.options import Selection
    from thrustmap.fitting.selection.points import select
    from thrustmap.rig.sim.physics import true_throttle_fraction
    from thrustmap.rig.sim.presets import preset

    ds = load_dataset(csv)
    tmap = fit_map([ds]).map
    pts = select(ds, Selection())
    keep = pts.thrust_n > 0.05 * pts.thrust_n.max()  # every point but the motor at rest
    t, b = pts.thrust_n[keep], pts.voltage_v[keep]
    truth = to_pct(np.asarray(true_throttle_fraction(preset(plant), 1, t, b), dtype=float))
    err = np.abs(tmap.throttle_pct(t, b, corrected=False) - truth)
    assert np.all(np.isfinite(err)), err
    return float(err.mean()), float(err.max()), int(keep.sum())
