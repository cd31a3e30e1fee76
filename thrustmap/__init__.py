"""thrustmap: calibrate multirotor thrust maps on a bench and correct them from flight logs.

The Python API (each imported on first use, so ``import thrustmap`` costs nothing):

- stand data to a map: ``load_stand_logs``, ``fit``, ``compare``, ``load_map``, ``save_map``,
  ``predict`` (a ``Prediction`` with its interval), ``export``;
- flight logs to γ(B): ``read_flight_log``, ``extract_df``, ``fit_gamma``, ``corrected_map``;
- the bench: ``open_bench`` (a session on devices given by URL; it chooses its clock),
  ``plans`` (the plan builders: ``plans.stairs``, ``plans.steps``, ``plans.ramp``,
  ``plans.adaptive`` with a ``MapChooser``), ``Limits`` (the interlocks), ``RunResult``, and
  ``run_script``/``ScriptBench``/``script_exit_code`` (a standalone bench script: its arguments, the
  operator's confirmation, the run; ``scripts/``).

See ``help(thrustmap.fit)`` and the API page of the docs (docs/api.md).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # for type checkers and IDEs; at run time each name loads on first use
    from thrustmap.api import (
        Prediction,
        compare,
        corrected_map,
        export,
        extract_df,
        fit,
        fit_gamma,
        load_map,
        load_stand_logs,
        open_bench,
        predict,
        read_flight_log,
        save_map,
    )
    from thrustmap.fitting.adaptive import MapChooser
    from thrustmap.rig import plans
    from thrustmap.rig.interlocks import Limits
    from thrustmap.rig.run_types import RunResult
    from thrustmap.rig.script import ScriptBench, run_script, script_exit_code

#: the public API: name -> the module that defines it
API = {
    **dict.fromkeys(
        (
            "Prediction",
            "compare",
            "corrected_map",
            "export",
            "extract_df",
            "fit",
            "fit_gamma",
            "load_map",
            "load_stand_logs",
            "open_bench",
            "predict",
            "read_flight_log",
            "save_map",
        ),
        "thrustmap.api",
    ),
    "plans": "thrustmap.rig.plans",  # the module itself
    "MapChooser": "thrustmap.fitting.adaptive",
    "Limits": "thrustmap.rig.interlocks",
    "RunResult": "thrustmap.rig.run_types",
    "run_script": "thrustmap.rig.script",
    "ScriptBench": "thrustmap.rig.script",
    "script_exit_code": "thrustmap.rig.script",
}
__all__ = [
    "Limits",
    "MapChooser",
    "Prediction",
    "RunResult",
    "ScriptBench",
    "__version__",
    "compare",
    "corrected_map",
    "export",
    "extract_df",
    "fit",
    "fit_gamma",
    "load_map",
    "load_stand_logs",
    "open_bench",
    "plans",
    "predict",
    "read_flight_log",
    "run_script",
    "save_map",
    "script_exit_code",
]


def __getattr__(name: str) -> Any:
    # Loaded when asked for: importing the API's modules (numpy, scipy) or importlib.metadata
    # (~60 ms) would otherwise be paid by every CLI start.
    if name == "__version__":
        from thrustmap.core.version import package_version

        value: Any = package_version()
    elif name in API:
        import importlib

        module = importlib.import_module(API[name])
        value = module if module.__name__.endswith(f".{name}") else getattr(module, name)
    else:
        raise AttributeError(f"module 'thrustmap' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *API, "__version__"})
