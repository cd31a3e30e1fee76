"""Devices and experiments: stand and flight-controller drivers, the simulator, sweep plans,
the runner with its interlocks, and the recorder that writes Ds logs.

- ``session``: ONE bench session (open devices, signals, clock rule, verified stop, exit codes)
  that ``thrustmap sweep``/``spin`` and ``scripts/`` run; ``script``: what a bench script calls.
- ``runner``: executes a plan (the sweep, and the spin) with the interlocks (``run_types``: its
  config, live status and result); ``settle``: its live settle/at-rest detectors;
  ``interlocks``: the limits table; ``plans`` (over ``segments`` and ``adaptive_plan``);
  ``sigterm``: SIGTERM unwinds like Ctrl-C; ``watchdog``: the motor-stop process (``watchdog_handle``: its handle).
- ``devices/``: the driver registry (detection, ports, probe, opening by URL).
- ``fc/``, ``stand/``: the drivers; ``sim/``: the simulated peers and physics.
"""
