"""How far outside its data a map is trusted: the growth of its interval beyond the thrust
reached and the limit past which no benchmark shows it holds (the one place both live).

``benchmarks/bench_extrapolation.py`` fits maps on the lower part of a recording's thrust range,
at one voltage, or on one recording, and scores the rest, the other voltage, the other
recording, on every rig we have. ``EVIDENCE`` is the table it printed for the tuning rigs
(``--table``); the growth is the smallest that holds >= 90 % of those points in every bin, and
the limits are where the bins with evidence end. The set-aside rigs are scored by the benchmark,
never used here.
"""

from __future__ import annotations

from dataclasses import dataclass

#: the interval beyond the thrust reached widens by (1 + growth·√(T / reach at B - 1)): at
#: twice the reach it is (1 + growth) times its width at the reach. The square root: on every
#: rig the error jumps just past the reach and then grows about linearly
EXTRAPOLATION_GROWTH = 8.5  # --calibrate: 8.25 (the simulated Crazyflie's first bins set it)
#: a map fitted on one recording: a second recording of the same rotor scatters this many times
#: more than the recording's own held-out points (added in quadrature to the interval)
RECORDING_FACTOR = 1.45
RECORDING_WHAT = "a second recording of the same rotor (one recording's scatter understates it)"
#: T / reach at B beyond which the benchmark has no evidence (predict refuses past it): maps
#: fitted on half a recording's thrust reach twice the reach; past it only Strawson a-c and the
#: simulated xNova have ten points or more in a bin (xNova SR 4, the simulated Crazyflie none)
EVIDENCE_LIMIT_THRUST_RATIO = 2.0
#: |ln(B / voltage measured near T)| beyond which the benchmark has no evidence: the farthest
#: pairs are 2S and 3S of one motor (ln 1.5 = 0.41 apart, a little more under load); 0.5 is
#: 65 % above or 39 % below the voltages measured
EVIDENCE_LIMIT_VOLTAGE_LOG = 0.5
#: the goal every published bin meets
COVERAGE_GOAL_PCT = 90.0
#: bin widths of the table
THRUST_BIN = 0.25
VOLTAGE_BIN = 0.1
#: the command that prints the table
COMMAND = "python benchmarks/bench_extrapolation.py"


@dataclass(frozen=True)
class Bin:
    """One row of the benchmark's table: held-out points at a distance outside their map's
    supported region (``axis`` "thrust": T / reach in (lo, hi], voltage inside; "voltage":
    |ln(B / B_measured)| in (lo, hi])."""

    rigs: str
    axis: str
    lo: float
    hi: float
    n: int
    median_error_pct: float
    coverage_pct: float  # with EXTRAPOLATION_GROWTH
    coverage_main_pct: float  # with main 19a0a12's interval (its growth, κ 12.5, no r term)


#: the benchmark's table within the limit (``--table``), the tuning rigs (xNova SR, Strawson
#: motors a-c, simulator seeds 1-3) and the set-aside rigs (xNova MR, Strawson d-f, simulator
#: seeds 4-6, diegosdantonio/thruststand_test's public RCbenchmark tests), each pooled; the
#: per-rig rows are printed by the benchmark
EVIDENCE: tuple[Bin, ...] = (
    Bin("tuning rigs", "thrust", 1.00, 1.25, 328, 1.42, 99.7, 77.1),
    Bin("tuning rigs", "thrust", 1.25, 1.50, 321, 2.59, 100.0, 55.8),
    Bin("tuning rigs", "thrust", 1.50, 1.75, 282, 4.11, 99.6, 42.6),
    Bin("tuning rigs", "thrust", 1.75, 2.00, 144, 7.80, 99.3, 32.6),
    Bin("tuning rigs", "voltage", 0.00, 0.10, 407, 0.48, 91.2, 82.3),
    Bin("tuning rigs", "voltage", 0.10, 0.20, 133, 0.78, 100.0, 97.7),
    Bin("tuning rigs", "voltage", 0.20, 0.30, 31, 3.16, 96.8, 87.1),
    Bin("tuning rigs", "voltage", 0.30, 0.40, 153, 2.27, 98.0, 96.7),
    Bin("tuning rigs", "voltage", 0.40, 0.50, 455, 2.07, 99.6, 97.6),
    Bin("set-aside rigs", "thrust", 1.00, 1.25, 691, 1.60, 95.4, 65.6),
    Bin("set-aside rigs", "thrust", 1.25, 1.50, 796, 3.08, 81.3, 45.0),
    Bin("set-aside rigs", "thrust", 1.50, 1.75, 820, 3.25, 96.0, 58.4),
    Bin("set-aside rigs", "thrust", 1.75, 2.00, 379, 3.13, 99.7, 62.8),
    Bin("set-aside rigs", "voltage", 0.00, 0.10, 659, 0.68, 81.8, 75.1),
    Bin("set-aside rigs", "voltage", 0.10, 0.20, 128, 0.97, 99.2, 89.1),
    Bin("set-aside rigs", "voltage", 0.30, 0.40, 183, 2.35, 99.5, 98.4),
    Bin("set-aside rigs", "voltage", 0.40, 0.50, 679, 2.22, 91.3, 88.5),
)
