"""Flights with the defects real fleets show (issue 21): a touchdown mid-log that no land flag
reports, an altitude that drifts toward landing, brief command dips the rotors do not follow,
and (with paused logging) events that cannot be timed. Each must give a clean Df: at most 3 %
of its samples off the steady command/force ratio, at least 90 % of the steady flight kept."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from support import flight_defects as fd

from thrustmap.fitting.df.extraction import extract
from thrustmap.fitting.df_options import DfOptions
from thrustmap.flightlogs.detect import read_log
from thrustmap.flightlogs.series import Signal


def _judge(sim: fd.DefectFlight, t: pd.DataFrame) -> tuple[float, float]:
    ts = t["time_s"].to_numpy(float)
    off = fd.off_ratio(
        ts, t["thrust_cmd_norm"].to_numpy(float), t["accel_up_mps2"].to_numpy(float), sim
    )
    return off, fd.kept_of_steady(ts, sim)


@pytest.mark.parametrize("kind", ["clean", "touchdown", "drift", "dips"])
def test_defect_gives_clean_df(kind: str) -> None:
    sim = fd.simulate(kind)
    df = extract([sim.log], DfOptions(mass_kg=1.0))
    off, kept = _judge(sim, df.table)
    assert len(df.table) >= 100
    assert off <= 0.03, f"{off:.1%} of the Df off the steady ratio"
    assert kept >= 0.90, f"only {kept:.0%} of the steady flight kept"


@pytest.mark.parametrize("drop", [(), ("height_m",), ("height_m", "hover_throttle")])
def test_touchdown_mid_log_is_dropped_and_reported(drop: tuple[str, ...]) -> None:
    """10 s back on the ground mid-log, the land detector silent: by the altitude back at the
    ground level when there is one, else by physics (command well below hover, a_up = g)."""
    sim = fd.simulate("touchdown")
    for k in drop:
        del sim.log.extras[k]
    df = extract([sim.log], DfOptions(mass_kg=1.0))
    steps = {s.name: s.dropped_s for s in df.reports[0].steps}
    rule = "ground-altitude" if not drop else "ground-physics"
    assert steps[rule] >= 5.0, steps
    t = df.table["time_s"].to_numpy(float)
    assert not ((t > 54.0) & (t < 64.0)).any()  # on the ground 54..64 s
    off, kept = _judge(sim, df.table)
    assert off <= 0.03 and kept >= 0.90


def test_altitude_drift_warns_and_does_not_cut_the_flight() -> None:
    sim = fd.simulate("drift")
    df = extract([sim.log], DfOptions(mass_kg=1.0))
    assert any("landing level +1.2 m from the takeoff level" in w for w in df.reports[0].warnings)
    t = df.table["time_s"].to_numpy(float)
    assert t.min() < 15.0 and t.max() > 105.0


def test_command_dips_are_dropped_with_the_rotor_lag() -> None:
    sim = fd.simulate("dips")
    df = extract([sim.log], DfOptions(mass_kg=1.0))
    steps = {s.name: s.dropped_s for s in df.reports[0].steps}
    assert steps["transient"] > 5.0
    t = df.table["time_s"].to_numpy(float)
    dips = sim.time_s[np.diff(sim.log.thrust_cmd_norm.values, prepend=0.0) < -0.03]  # type: ignore[union-attr]
    # no Df sample within the rotor lag of a dip's start
    assert np.min(np.abs(t[:, None] - dips[None, :])) > 0.1


def test_untimed_events_with_paused_logging(tmp_path: Path) -> None:
    """ArduCopter 3.3-dev: EV without time stamps, logging paused while disarmed, the events
    of each pause written on resuming. Armed state from the motor outputs, pauses as flight
    boundaries, a warning that events were untimed; every flight gives clean Df."""
    path = tmp_path / "copter33_paused.bin"
    flights = fd.write_copter33_paused(str(path))
    (fl,) = read_log(path)
    assert fl.armed is not None and "motor outputs" in fl.armed.origin
    df = extract([fl], DfOptions(mass_kg=1.0))
    assert any("events untimed" in w for w in df.reports[0].warnings)
    t = df.table
    for start, sim in flights:
        rows = t[(t["time_s"] >= start) & (t["time_s"] <= start + sim.time_s[-1])]
        shifted = rows.assign(time_s=rows["time_s"] - start)
        off, kept = _judge(sim, shifted)
        assert len(rows) >= 100
        assert off <= 0.03 and kept >= 0.90, (start, off, kept)


def test_range_sensor_judges_height_where_valid() -> None:
    """With a valid range sensor the drifting altitude is not used at all (no drift warning);
    one valid for too little of the flight is reported and the altitude is used."""
    sim = fd.simulate("drift")
    hs = sim.log.extras["height_m"]
    z = np.clip(hs.values - np.interp(hs.time_s, [0, 104, 116], [0, 0, 1.2]), 0.0, None) + 0.1
    sim.log.extras["range_m"] = Signal(hs.time_s, z, "m", "sim RFND.Dist")
    df = extract([sim.log], DfOptions(mass_kg=1.0))
    assert not any("landing level" in w for w in df.reports[0].warnings)
    assert "sim RFND.Dist" in next(s.reason for s in df.reports[0].steps if s.name == "height")
    off, kept = _judge(sim, df.table)
    assert off <= 0.03 and kept >= 0.90
    patchy = np.where((hs.time_s % 10.0) < 5.0, np.nan, z)
    sim.log.extras["range_m"] = Signal(hs.time_s, patchy, "m", "sim RFND.Dist")
    df = extract([sim.log], DfOptions(mass_kg=1.0))
    assert any("sim RFND.Dist not used" in w for w in df.reports[0].warnings)


def test_low_hover_with_drift_under_a_metre_is_not_taken_for_ground() -> None:
    """A hover at 0.6-0.9 m whose altitude drifts 0.8 m toward landing: the levels agree
    within a metre, yet no stretch of the flight may read as back on the ground."""
    sim = fd.simulate("clean")
    hs = sim.log.extras["height_m"]
    t = hs.time_s
    drift = 0.8 * np.clip((t - 4.0) / 112.0, 0.0, 1.0)
    low = np.clip(hs.values, 0.0, None) * 0.6 + drift
    sim.log.extras["height_m"] = Signal(t, low, "m", "sim CTUN.Alt (low, drifting)")
    df = extract([sim.log], DfOptions(mass_kg=1.0))
    steps = {s.name: s.dropped_s for s in df.reports[0].steps}
    assert steps.get("ground-altitude", 0.0) == 0.0, steps
    off, kept = _judge(sim, df.table)
    assert off <= 0.03 and kept >= 0.90
