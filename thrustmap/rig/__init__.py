"""Devices and experiments: stand and flight-controller drivers, the simulator, sweep plans,
the runner with its interlocks, and the recorder that writes Ds logs.

- ``session``: ONE bench session (open devices, signals, clock rule, verified stop, exit codes)
  that ``thrustmap sweep``/``spin`` and ``scripts/`` run; ``script``: what a bench script calls.
- ``runner``: executes a plan (the sweep, and the spin) with the interlocks; ``settle``: its live
  settle/at-rest detectors; ``interlocks``: the limits table; ``plans``; ``safety``: signals.
- ``devices/``: the driver registry (detection, ports, probe); ``connect``: open by URL.
- ``fc/``, ``stand/``: the drivers; ``sim/``: the simulated peers and physics.
"""
