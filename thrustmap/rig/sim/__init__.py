"""The built-in simulator: physics (``physics``) behind byte-level simulated peers that speak
the real wire protocols, so drivers cannot tell a simulated peer from a real one."""
