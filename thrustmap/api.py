"""thrustmap's public Python API: the README's tour as functions (``import thrustmap``).

Each function is a thin, typed entry over the module that does the work; the CLI commands go
through the same modules, so a script and ``thrustmap fit`` give the same map. Everything is
imported when first called, so ``import thrustmap`` stays instant.

Stand data to a map::

    logs = thrustmap.load_stand_logs(["sr-1.csv", "sr-2.csv"])
    outcome = thrustmap.fit(logs)                 # outcome.map, outcome.warnings ...
    thrustmap.save_map(outcome.map, "map.json", inputs=["sr-1.csv", "sr-2.csv"])
    p = thrustmap.predict(outcome.map, thrust_n=4.2, voltage_v=24.0)
    text = thrustmap.export(outcome.map, "px4").text

Flight logs to γ(B)::

    flights = thrustmap.read_flight_log("hover.ulg")
    df = thrustmap.extract_df(flights, mass_kg=1.5, tmap=tmap)
    gamma = thrustmap.fit_gamma(df, tmap)
    corrected = thrustmap.corrected_map(tmap, gamma)

A bench (the session picks its clock: simulated time when every URL is simulated)::

    with thrustmap.open_bench(stand="sim://tyto-1585", throttle="sim://px4") as bench:
        result = bench.sweep(thrustmap.plans.stairs(10, 40, 10, dwell_s=1), "run.csv")
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from thrustmap.fitting.dataset import Dataset
    from thrustmap.fitting.df.table import Df
    from thrustmap.fitting.df_options import DfOptions
    from thrustmap.fitting.export.encodings import ExportResult
    from thrustmap.fitting.fit.fitmap import FitOutcome
    from thrustmap.fitting.fit.validation import Row
    from thrustmap.fitting.gamma import GammaFit
    from thrustmap.fitting.loaders.load import ColumnMap
    from thrustmap.fitting.mapfile import ThrustMap
    from thrustmap.fitting.names import Loss, Validation
    from thrustmap.fitting.selection.options import Selection
    from thrustmap.flightlogs.series import FlightLog
    from thrustmap.rig.session import BenchSession

PathLike = str | Path

__all__ = [
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
]


# -- stand logs, fits, maps ---------------------------------------------------------------------


def load_stand_logs(
    paths: PathLike | Sequence[PathLike], column_map: ColumnMap | None = None
) -> list[Dataset]:
    """Load stand logs (RCbenchmark/Tyto, Flight Stand, Crazyflie, thrustmap's own Ds log, or
    any CSV through a ``ColumnMap``), each format detected from its header. A bad file raises
    ``DataFormatError`` naming the file, line and column."""
    from thrustmap.fitting.loaders.load import load_datasets

    return load_datasets([paths] if isinstance(paths, (str, Path)) else paths, column_map)


def _datasets(logs: PathLike | Sequence[PathLike] | Sequence[Dataset]) -> list[Dataset]:
    if isinstance(logs, (str, Path)):
        return load_stand_logs(logs)
    items = list(logs)
    if all(isinstance(x, (str, Path)) for x in items):
        return load_stand_logs(items)  # type: ignore[arg-type]
    return items  # type: ignore[return-value]


def fit(
    logs: PathLike | Sequence[PathLike] | Sequence[Dataset],
    *,
    model: str = "motor",
    loss: Loss = "l2",
    selection: Selection | None = None,
    strategy: str | None = None,
) -> FitOutcome:
    """Fit a thrust map Th = f(T, B) to stand logs (paths or loaded datasets), as
    ``thrustmap fit``: steady-state selection, the model fit, its checks and prediction
    interval. The map is ``.map``; what the fit advises is logged and kept on the outcome."""
    from thrustmap.fitting.fit.fitmap import fit_map

    return fit_map(_datasets(logs), model=model, loss=loss, selection=selection, strategy=strategy)


def compare(
    logs: PathLike | Sequence[PathLike] | Sequence[Dataset],
    models: Sequence[str] = ("motor", "poly2"),
    validation: Validation = "by-file",
    *,
    loss: Loss = "l2",
    selection: Selection | None = None,
    folds: int = 5,
) -> list[Row]:
    """Score models under one validation mode, as ``thrustmap compare``: one row per model,
    its headline error over every held-out point."""
    from thrustmap.fitting.fit.validation import compare as compare_models

    return compare_models(
        _datasets(logs), list(models), validation, loss=loss, selection=selection, folds=folds
    )


def load_map(path: PathLike) -> ThrustMap:
    """Read a map file (every number that evaluates it is checked; errors name the field)."""
    from thrustmap.fitting.mapfile import ThrustMap

    return ThrustMap.load(path)


def save_map(tmap: ThrustMap, path: PathLike, *, inputs: Sequence[PathLike] = ()) -> Path:
    """Write a map atomically; refused (``ConfigError``) when ``path`` is one of ``inputs``
    (the logs it came from are never overwritten) or its folder cannot be written."""
    from thrustmap.core.files import atomic_write_text, check_output_path

    check_output_path(path, inputs=[*inputs], what="map output")
    atomic_write_text(path, tmap.dumps())
    return Path(path)


@dataclass(frozen=True)
class Prediction:
    """The throttle a map gives for a thrust at a voltage, with its prediction interval."""

    thrust_n: float
    voltage_v: float
    throttle_pct: float  # % of the map's throttle scale (may leave 0..100: unreachable)
    throttle_native: float  # in the scale's own unit (µs, DShot value, ...)
    throttle_unit: str
    interval_pct: float | None  # 95 % half-width, % throttle (None: the map has none)
    inside_supported_region: bool  # where the map's data are
    corrected: bool  # γ(B) applied

    @property
    def reachable(self) -> bool:
        """Whether the motor can make this thrust at this voltage (per the map)."""
        return 0.0 <= self.throttle_pct <= 100.0


def predict(
    tmap: ThrustMap, thrust_n: float, voltage_v: float, *, corrected: bool = True
) -> Prediction:
    """Throttle for ``thrust_n`` (per rotor, N) at ``voltage_v``, as ``thrustmap predict``;
    a thrust or voltage that cannot be physical is refused (``ConfigError``)."""
    from thrustmap.core import physical
    from thrustmap.core.errors import ConfigError

    physical.rotor_thrust_n(thrust_n, "thrust_n")
    physical.battery_voltage_v(voltage_v, "voltage_v")
    pct = float(tmap.throttle_pct(thrust_n, voltage_v, corrected=corrected))
    if pct != pct:  # NaN
        raise ConfigError(f"the map gives no finite answer at T={thrust_n:g} N, B={voltage_v:g} V")
    half = tmap.interval_pct(thrust_n, voltage_v, corrected=corrected)
    model_t = tmap.model_thrust(thrust_n, voltage_v, corrected=corrected)
    return Prediction(
        thrust_n=float(thrust_n),
        voltage_v=float(voltage_v),
        throttle_pct=pct,
        throttle_native=float(tmap.throttle_scale.from_pct(pct)),
        throttle_unit=tmap.throttle_scale.unit,
        interval_pct=None if half is None else float(half),
        inside_supported_region=bool(tmap.in_box(model_t, voltage_v)),
        corrected=corrected and tmap.correction is not None,
    )


def export(tmap: ThrustMap, target: str, **options: Any) -> ExportResult:
    """Export a map for a throttle encoding or a firmware (``px4``, ``ardupilot``,
    ``betaflight``, ``c-header``, ...), as ``thrustmap export``; ``options`` are
    ``ExportOptions`` fields (``firmware="4.6"``, ``mass_kg=``, ``rotors=``, ...). The text
    is ``.text``, the fitted values ``.values`` and their residual ``.residual``."""
    from thrustmap.fitting.export.encodings import ExportOptions
    from thrustmap.fitting.export.targets import export_map

    return export_map(tmap, target, ExportOptions(**options) if options else None)


# -- flight logs ---------------------------------------------------------------------------------


def read_flight_log(path: PathLike, *, format: str | None = None) -> list[FlightLog]:
    """Every flight in a flight log (ULog, DataFlash .bin, tlog, Betaflight blackbox, rosbag,
    the paper's CSV), its format detected unless ``format`` names a reader."""
    from thrustmap.flightlogs.detect import read_log

    return read_log(path, format=format)


def extract_df(
    flights: Sequence[FlightLog],
    *,
    mass_kg: float | None = None,
    tmap: ThrustMap | None = None,
    options: DfOptions | None = None,
) -> Df:
    """Df (the steady-hover samples the correction is fitted on) from flights, as
    ``thrustmap flightlog extract``: ``options`` are the filters (``DfOptions``; its defaults
    are the CLI's), ``mass_kg`` the vehicle's mass, ``tmap`` the stand map that turns motor
    outputs into thrust. ``.table`` is the table, ``.reports`` what each filter dropped."""
    from thrustmap.fitting.df.extraction import extract
    from thrustmap.fitting.df_options import DfOptions

    opts = options or DfOptions()
    if mass_kg is not None:
        opts = replace(opts, mass_kg=mass_kg)
    return extract(list(flights), opts, tmap)


def fit_gamma(
    df: Df,
    tmap: ThrustMap,
    *,
    loss: Loss = "l1",
    degree: int | None = None,
    rotors: int | None = None,
) -> GammaFit:
    """Fit the correction γ(B) on a Df against the stand map, as ``thrustmap gamma fit``
    (``degree=None`` chooses it by held-out error)."""
    from thrustmap.fitting.gamma import GammaOptions
    from thrustmap.fitting.gamma import fit_gamma as fit

    return fit(df.table, df.sources, tmap, GammaOptions(loss=loss, degree=degree), rotors=rotors)


def corrected_map(
    tmap: ThrustMap, gamma: GammaFit, *, sources: Sequence[dict[str, Any]] = (), force: bool = False
) -> ThrustMap:
    """The stand map with γ(B) attached (``predict`` and ``export`` then apply it). A γ that
    cannot be physical is refused (``FitError``) unless ``force``, which the map records."""
    from thrustmap.fitting.gamma import check_physical
    from thrustmap.fitting.gamma import corrected_map as attach

    forced = check_physical(gamma, force=force)
    return attach(tmap, gamma, list(sources), forced=forced)


# -- the bench -----------------------------------------------------------------------------------


def open_bench(stand: str | None = None, throttle: str | None = None, **rig: Any) -> BenchSession:
    """A bench session on devices given by URL (``sim://...``, a serial port, ``tcp://``,
    ``udpin:...``), to use in a ``with`` block: inside it, ``.sweep(plan, "run.csv",
    limits=...)`` runs a plan with the interlocks and ``.spin(...)`` one capped spin; every way
    out stops the motor and verifies the stop. ``rig`` are ``Rig`` fields (``kind``,
    ``motor``, ``calibration``, ...). The session chooses its clock: simulated time when every
    URL is simulated, else the monotonic clock. Opening nothing spins a motor."""
    from thrustmap.rig.session import BenchSession, Rig

    return BenchSession(Rig(stand=stand, throttle=throttle, **rig))
