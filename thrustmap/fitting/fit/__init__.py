"""Fit thrust maps from Ds, validate them, and score maps on new data.

``fit_map``: selection -> model fit -> checks (monotone in T, conditioning) -> ``ThrustMap``.
``compare``: several models under one validation mode (in-sample, by-file, k-fold); the headline
counts every held-out point, with the points inside and outside the training points' supported
region beside it.
``evaluate``: an existing map against new files.

The package, one module per job, each imported by its own path (``thrustmap.fitting.fit.<module>``; this file re-exports no name):
``coefficients`` (the pooled points, coefficients, their covariance), ``fitmap`` (``fit_map``
and its interval, checks and advice), ``backemf`` (the back-EMF trial), ``validation``
(``validate``, ``compare``, ``evaluate``). No module imports another's private name.
"""
