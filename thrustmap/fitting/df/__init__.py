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

The package, one module per job, each imported by its own path (``thrustmap.fitting.df.<module>``; this file re-exports no name):
``options`` (DfOptions, the constants, the report types), ``table`` (the Df table),
``resample`` (one timeline: bins, running statistics, time sanity), ``airborne`` (the rules that
tell ground from free flight, the rest calibration), ``thrust`` (T_c from the motor outputs
through the stand map), ``extraction`` (the filters in order; ``extract``), ``dffile`` (the CSV
and its sidecar). No module imports another's private name.
"""
