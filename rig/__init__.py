"""Devices and experiments: stand and flight-controller drivers, the simulator, sweep plans,
the runner with its interlocks, and the recorder that writes Ds logs."""

if __name__ != "thrustmap.rig":  # the checkout's top-level folder, imported by its bare name
    raise ImportError(f"import thrustmap.rig, not {__name__}: one module, one name")
