"""Fit thrust maps from Ds, validate them, and score maps on new data.

``fit_map``: selection -> model fit -> checks (monotone in T, conditioning) -> ``ThrustMap``.
``compare``: several models under one validation mode (in-sample, by-file, k-fold); the headline
counts every held-out point, with the points inside and outside the training points' supported
region beside it.
``evaluate``: an existing map against new files.

The package, one module per job (``thrustmap.fitting.fit`` keeps every public name):
``coefficients`` (the pooled points, coefficients, their covariance), ``fitmap`` (``fit_map``
and its interval, checks and advice), ``backemf`` (the back-EMF trial), ``validation``
(``validate``, ``compare``, ``evaluate``). No module imports another's private name.
"""

from thrustmap.fitting.fit.backemf import Predictor, backemf_rows
from thrustmap.fitting.fit.coefficients import (
    Pool,
    fit_coefficients,
    identify_coefficients,
    parameter_covariance,
    pool,
)
from thrustmap.fitting.fit.fitmap import (
    ILL_CONDITIONED,
    KIND_NAMES,
    REPORT_WEIGHT_RATIO,
    VOLTAGE_TERM_MARGIN,
    FitOutcome,
    bound_term,
    check_map,
    fit_map,
    model_interval,
    spin_up_block,
    systematic_terms,
    weighting_line,
)
from thrustmap.fitting.fit.validation import Row, compare, evaluate, validate

__all__ = [
    "ILL_CONDITIONED",
    "KIND_NAMES",
    "REPORT_WEIGHT_RATIO",
    "VOLTAGE_TERM_MARGIN",
    "FitOutcome",
    "Pool",
    "Predictor",
    "Row",
    "backemf_rows",
    "bound_term",
    "check_map",
    "compare",
    "evaluate",
    "fit_coefficients",
    "fit_map",
    "identify_coefficients",
    "model_interval",
    "parameter_covariance",
    "pool",
    "spin_up_block",
    "systematic_terms",
    "validate",
    "weighting_line",
]
