"""Load Ds (bench data) from stand logs, auto-detected by header.

Formats: RCbenchmark (Tyto app) logs and their spreadsheet re-saves, Flight Stand exports,
Crazyflie system-id logs, the project's own Ds log (:mod:`thrustmap.core.stand_recording`), and any CSV through an
explicit ``ColumnMap``. Every error names the file, the line or column, and what was expected.

What a loader assumes, it says (``Dataset.meta`` and a logged warning):

- the shape of the rows: a step-summary export (one averaged row per throttle step) is marked
  ``meta["layout"]``; a sparse log (each sensor written when it updates) keeps the rows with a
  thrust reading and carries the last command and voltage forward only within a bounded age;
- a last row without a line end that is cut short (a partial write) is dropped;
- units checked against physics: a battery voltage (1S..14S; millivolts are converted), an ESC
  pulse of 500..2600 µs (a spreadsheet's ``1.500`` is 1500 µs), per-rotor thrust a stand can
  measure, and thrust per electrical watt a propeller can make; anything else is refused with
  the file, line and column. A written ``nan`` or ``inf`` is never a measurement.

The package, one module per job, each imported by its own path (``thrustmap.fitting.loaders.<module>``; this file re-exports no name):
``load`` (``load_dataset``, ``ColumnMap``), ``formats`` (each format's reader, ``FORMATS``),
``table`` (the delimited text, its columns and cells), ``assemble`` (columns to a Dataset,
sparse logs), ``checks`` (the unit checks against physics). No module imports another's private
name.
"""
