"""Devices and experiments: stand and flight-controller drivers, the simulator, sweep plans,
the runner with its interlocks, and the recorder that writes Ds logs."""
