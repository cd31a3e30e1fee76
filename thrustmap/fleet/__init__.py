"""Fleet scale: Df and γ(B) over many flight logs, on local worker processes or Dask.

- :mod:`thrustmap.fleet.discover` finds the logs (folders, globs, files);
- :mod:`thrustmap.fleet.task` runs one log through exactly the rules of ``flightlog extract``
  (:func:`thrustmap.fitting.df.extract`) and returns its outcome (never raises for a bad log);
- :mod:`thrustmap.fleet.table` is the fleet table (Parquet, one row per log);
- :mod:`thrustmap.fleet.run` plans the tasks and runs them serially, on local workers or on a
  Dask cluster, resumably;
- :mod:`thrustmap.fleet.local` is the local workers: processes forked from the command;
- :mod:`thrustmap.fleet.groups` groups logs by airframe and fits γ(B) per group with
  :func:`thrustmap.fitting.gamma.fit_gamma`, as ``gamma fit`` does;
- :mod:`thrustmap.fleet.report` writes the fleet HTML report.

Dask and pyarrow are imported only where they are used (``pip install 'thrustmap[fleet]'``);
forked local workers need neither.
"""
