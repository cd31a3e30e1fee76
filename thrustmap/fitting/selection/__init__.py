"""Which samples a fit sees: range filters and steady-state extraction.

Range filters use the seed paper's strict inequalities, in the data's native units.

Steady state (default): a step sweep holds each throttle level for seconds, but the rotor
needs time to spin up and the stand averages over its own window, so the first samples of each
plateau are transients. For every plateau (consecutive samples at one throttle) we estimate the
thrust noise from the second half of the plateau, drop the leading samples until thrust has
settled inside that noise band, and average the rest into one (T, B, Th) point. On ramps,
samples are kept only where the throttle slews slowly enough that rotor lag costs less than
``lag_budget_pct`` of throttle (quasi-static). ``all_samples`` reproduces the paper (no
extraction).

Sensors, not samples: a load cell that updates every ~10 samples and holds its value in between
(sample-and-hold, e.g. the Crazyflie system-id stand) is detected from its exact repeats, and
settling, noise and plateau length are judged on its UPDATES. A plateau whose kept part still
trends (the means of its two halves differ beyond the noise) is dropped.

Quasi-static staircases: a command held for about one sensor update per step (the Crazyflie
system-id deck: 10 ms rows, a new command every 100 ms, a load cell converting at ~10 SPS) is a
slow ramp seen through the sensor, not a staircase of unsettled plateaus. A pair of adjacent
legs (up then down, or down then up; at least ``min_stair_legs`` stairs each) is treated so
when its stairs last fewer than ``quasi_static_updates`` sensor updates or less than
``quasi_static_lags`` times the lag seen between the legs (the transient never dies out inside
a stair). Each up stair is paired with the down leg read at the same command (interpolated, so
the levels need not match): the rotor and a held load cell lag low going up and high coming
down, in proportion to how fast each leg moves, so the two readings weighted by the other
leg's rate cancel the lag to first order (no time column needed; with one, the lag left
between the legs is reported in seconds). The turning stair has no counterpart and is dropped
unless it was held long enough to settle. A pair whose voltages differ by more than
``pair_voltage_rel`` (the battery sagged between the legs) is dropped, and so is a pair where
one leg reads next to nothing (under ``stall_fraction`` of the other above the rest reading: a
rotor that had not started on the way up). ``describe`` says in one line what was kept.

Points where the rotor is stopped (command at the bottom of the scale, or rpm zero where the
log has rpm) read the load cell's offset: tare information, reported. A rotor at rest makes no
thrust, so when a rest plateau measures that offset (``rest_zero``: enough samples, beyond its
own noise) every point of the file is read from it and the rest points, being the zero, are not
map points (the xNova steps file rests at 0.061 N, its sister file at 0.004 N: read raw, the
lower-voltage file seemed to need less throttle at equal thrust, which no motor does). A positive command
that did not turn the rotor (ESC dead band, rotor not started) is not a map point and is dropped;
zero-command points are dropped too with ``drop_tare_points``.
Logs recorded by thrustmap say where each step begins and where the runner saw it settle: those
marks are used instead of being guessed again. Step-summary exports (one averaged row per step)
are steady-state points as they are. ``Points.report`` counts what each rule did.

The package, one module per job, each imported by its own path (``thrustmap.fitting.selection.<module>``; this file re-exports no name):
``options`` (Selection, the sample roles), ``points`` (``select`` and ``Points``), ``rest`` (the
rotor at rest, the load cell's zero), ``plateaus`` (levels, settling, sensor updates), ``stairs``
(legs, pairing, disagreement), ``creep`` (a creeping load cell), ``steady`` (the extraction in
order, ramps included), ``describe`` (one line for the CLI). No module imports another's
private name.
"""
