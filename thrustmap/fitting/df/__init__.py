"""Df: the flight samples the correction factor is fitted on (seed paper section 3.4).

From each flight log keep the samples where the paper's assumptions hold: armed and airborne,
away from takeoff/landing transients, near hover (upward specific force close to g, small tilt).
All streams are resampled onto one timeline (bin means at ``rate_hz``; a stream with no sample
within ``max_gap_s`` of a bin leaves it empty). Then:

- F_m = m · a_up (collective, N; mass from the user).
- T_c (collective, N) from the log's thrust command in newtons when it has one, otherwise from the
  motor outputs pushed through the stand map's forward direction, per rotor, summed over rotors
  (the stand map is per rotor). A normalised collective command is kept as ``thrust_cmd_norm``.

``extract()`` returns the table and a report of how much flight time each filter dropped and
why; ``write_df()`` writes the CSV plus a JSON sidecar naming the origin of every column.

The package, one module per job (``thrustmap.fitting.df`` keeps every public name):
``options`` (the constants, the report types; ``DfOptions`` is in
``thrustmap.fitting.df_options``, light enough for the CLI to build its options from), ``table`` (the Df table),
``resample`` (one timeline: bins, running statistics, time sanity), ``airborne`` (the rules that
tell ground from free flight, the rest calibration), ``thrust`` (T_c from the motor outputs
through the stand map), ``extraction`` (the filters in order; ``extract``), ``dffile`` (the CSV
and its sidecar). No module imports another's private name.
"""

from thrustmap.fitting.df.airborne import (
    REST_CAL_TOL_MPS2,
    REST_MARGIN_S,
    REST_SPAN_S,
    REST_STEADY_MPS2,
    airborne_windows,
)
from thrustmap.fitting.df.dffile import read_df, sidecar_path, write_df
from thrustmap.fitting.df.extraction import extract, extract_flight, extract_flight_columns
from thrustmap.fitting.df.options import (
    DF_FORMAT,
    G0,
    GROUND_HEIGHT_SPREAD_M,
    MIN_ACCEL_RATE_HZ,
    MIN_DF_SAMPLES,
    RANGE_COVERAGE,
    SATURATED_NORM,
    BoolArray,
    FilterStep,
    FlightReport,
)
from thrustmap.fitting.df.resample import (
    BINS_PER_SAMPLE,
    BINS_SLACK,
    TIME_JUMP_S,
    plausible_timeline,
)
from thrustmap.fitting.df.table import Columns, Df, hover_throttle
from thrustmap.fitting.df.thrust import (
    map_extrapolation,
    motor_pct_in_map_scale,
    select_motors,
    thrust_from_motors,
)
from thrustmap.fitting.df_options import DfOptions

__all__ = [
    "BINS_PER_SAMPLE",
    "BINS_SLACK",
    "DF_FORMAT",
    "G0",
    "GROUND_HEIGHT_SPREAD_M",
    "MIN_ACCEL_RATE_HZ",
    "MIN_DF_SAMPLES",
    "RANGE_COVERAGE",
    "REST_CAL_TOL_MPS2",
    "REST_MARGIN_S",
    "REST_SPAN_S",
    "REST_STEADY_MPS2",
    "SATURATED_NORM",
    "TIME_JUMP_S",
    "BoolArray",
    "Columns",
    "Df",
    "DfOptions",
    "FilterStep",
    "FlightReport",
    "airborne_windows",
    "extract",
    "extract_flight",
    "extract_flight_columns",
    "hover_throttle",
    "map_extrapolation",
    "motor_pct_in_map_scale",
    "plausible_timeline",
    "read_df",
    "select_motors",
    "sidecar_path",
    "thrust_from_motors",
    "write_df",
]
