"""Devices by URL: a registry of drivers (python-can style), and what iterates it.

- ``declaration``: what each driver declares (``Driver``): its kind, aliases, role (flight
  controller or stand), how to recognise it (simulated peer names, bytes it sends unasked,
  what a host writes to it) and how to open it; ``registry`` collects them (the built-in ones,
  declared in ``builtin``, loaded lazily).
- ``urls``: URL forms (device paths, ``sim://``, ``record://``, ``replay://``, ``socket://``,
  pymavlink ``udpin:``/``tcp:``) and opening a byte transport.
- ``detect``: what is on the other end of a URL (no I/O for sim/replay; a safe listen-then-ask
  probe for a real port), iterating the registry.
- ``ports``: serial ports described from their USB IDs (nothing opened).
- ``opening``: throttle outputs and stands opened through the registry.
- ``probe``: identity plus a short live reading (``thrustmap probe``).

Each is imported by its own path (``from thrustmap.rig.devices.opening import open_stand``).
Adding a device: declare a ``Driver`` in ``builtin`` (or ``registry.register`` one).
"""
