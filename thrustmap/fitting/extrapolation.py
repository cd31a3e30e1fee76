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
EXTRAPOLATION_GROWTH = 8.5
#: a map fitted on one recording: a second recording of the same rotor scatters this many times
#: more than the recording's own held-out points (added in quadrature to the interval)
RECORDING_FACTOR = 1.45
RECORDING_WHAT = "a second recording of the same rotor (one recording's scatter understates it)"
#: T / reach at B beyond which the benchmark has no evidence (predict refuses past it)
EVIDENCE_LIMIT_THRUST_RATIO = 2.0
#: |ln(B / voltage measured near T)| beyond which the benchmark has no evidence
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
    coverage_main_pct: float  # with main 19a0a12's growth


#: the tuning rigs' table (filled from the benchmark's --table output)
EVIDENCE: tuple[Bin, ...] = ()
