"""Thrust-map models: Th(%) = f(T [N], B [V]), all linear in their coefficients.

Polynomial surfaces (the seed paper's forms) are stored in the raw monomial basis the paper
writes them in, but fitted in a centred and scaled basis (T/Ts, (B-Bc)/Bs) and expanded back
exactly, so the narrow voltage range does not make the solve ill-conditioned.

``motor`` is physics-informed. A BLDC motor at duty d on a battery at B volts spins at
ω = Kv·(d·B − R·I) with current I = I0 + Q/Kt and propeller torque Q = kq·ω², and the propeller
pushes T = kt·ω². Eliminating ω = √(T/kt) gives the duty d·B = k0 + k1·√T + k2·T, so

    Th = c + (k0 + k1·√T + k2·T) / B,   with k0, k1, k2 ≥ 0 and c in ``OFFSET_RANGE_PCT``

(c absorbs the ESC's throttle-to-duty offset). The bounds are imposed by the solver (bounded
least squares, or bounded LP for L1), so every fitted map rises with T and never rises with B
for T ≥ 0 (∂Th/∂B = −(k0 + k1·√T + k2·T)/B² ≤ 0): physical by construction. It scales with 1/B
as a motor does and has four coefficients, so it extrapolates sanely.

Identification. At one battery voltage B0, c and k0/B0 are one number, so the data alone cannot
say how the map scales with B. Physics can: k0 is the resistive drop of the no-load current
(R·I0, a few tenths of a volt against a duty × voltage of several volts), while c is the ESC's
throttle offset (dead band / idle), which does not scale with voltage. ``motor`` therefore fits
the physics form with k0 = 0 unless the data can identify k0: only when the training voltages
span at least ``MIN_RELATIVE_SPAN`` of their mean over at least ``MIN_POINTS_PER_COEFFICIENT``
points per coefficient is k0 fitted (a real ESC's duty is not exactly proportional to
throttle, and enough data at several voltages measures that). A free fit (c and k0 unbounded)
that would break the physics (a negative no-load term, an offset outside its band) is named
in the reason and the bounded fit kept. Where the stand logged rpm and current,
``backemf_coefficients`` identifies the same form from B·d = Ke·ω + R·I instead
(fit/backemf.py keeps it only when by-file held-out error at another voltage confirms it). The
choice, its reason and the voltage scaling the map rests on are reported (:class:`Identification`).

Weights. ``motor`` weighs each point by the share of the command range it stands for
(:func:`command_weights`): a slow ramp's hundred samples over a few percent of throttle count
as much as the one plateau beside them would, so the map is met over the range a user
commands, not where the sweep lingered.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from thrustmap.core.errors import ConfigError, FitError
from thrustmap.fitting.names import MODEL_NAMES, Loss
from thrustmap.fitting.solve import solve

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
Features = Callable[[FloatArray, FloatArray], FloatArray]


@dataclass(frozen=True)
class Model:
    """A model linear in its coefficients: Th% = design(T, B) @ coefficients."""

    name: str
    formula: str
    description: str
    term_names: tuple[str, ...]
    uses_voltage: bool
    lower_bounds: tuple[float, ...] = field(default=())
    upper_bounds: tuple[float, ...] = field(default=())

    @property
    def n_coefficients(self) -> int:
        return len(self.term_names)

    def design(self, thrust_n: FloatArray, voltage_v: FloatArray) -> FloatArray:
        raise NotImplementedError

    def evaluate(
        self, coefficients: npt.ArrayLike, thrust_n: npt.ArrayLike, voltage_v: npt.ArrayLike
    ) -> FloatArray:
        t, b = np.broadcast_arrays(np.asarray(thrust_n, float), np.asarray(voltage_v, float))
        flat = self.design(t.ravel(), b.ravel()) @ np.asarray(coefficients, float)
        return np.asarray(flat.reshape(t.shape), dtype=float)

    #: validation may reuse one conditioned design across folds (False for special fits)
    linear_least_squares = True
    #: the model's voltage dependence comes from physics when the data has no voltage spread
    voltage_from_physics = False

    def conditioned(
        self, thrust_n: FloatArray, voltage_v: FloatArray
    ) -> tuple[FloatArray, Callable[[FloatArray], FloatArray]]:
        """A well-conditioned design for these points, and the map from its coefficients to
        the raw ones. Lower bounds (0 or -inf only) hold in both bases."""
        d = self.design(thrust_n, voltage_v)
        norms = np.linalg.norm(d, axis=0)
        norms[norms == 0] = 1.0
        return d / norms, lambda c: np.asarray(c, float) / norms

    def free_columns(self, thrust_n: FloatArray, voltage_v: FloatArray) -> list[int]:
        """Coefficients the data at these points determines (the others are held at 0)."""
        return list(range(self.n_coefficients))

    def lower(self) -> FloatArray | None:
        return np.array(self.lower_bounds, float) if self.lower_bounds else None

    def upper(self) -> FloatArray | None:
        return np.array(self.upper_bounds, float) if self.upper_bounds else None

    def fit_weights(
        self, throttle_pct: FloatArray, groups: IntArray | None = None
    ) -> FloatArray | None:
        """Each point's weight in the fit (None: all equal); ``groups``: each point's file."""
        return None

    def fit(
        self, thrust_n: FloatArray, voltage_v: FloatArray, throttle_pct: FloatArray, loss: Loss
    ) -> FloatArray:
        return self.identify(thrust_n, voltage_v, throttle_pct, loss)[0]

    def identify(
        self,
        thrust_n: FloatArray,
        voltage_v: FloatArray,
        throttle_pct: FloatArray,
        loss: Loss,
        groups: IntArray | None = None,
    ) -> tuple[FloatArray, Identification | None]:
        """Coefficients, and how the data identified them (None: every coefficient fitted);
        ``groups``: each point's file, for a model that weighs its points by file."""
        design, to_raw = self.conditioned(thrust_n, voltage_v)
        return to_raw(solve(design, throttle_pct, loss=loss, lower=self.lower())), None


@dataclass(frozen=True)
class Identification:
    """How a model's coefficients were identified, in one line a user can check."""

    form: str  # which form was fitted, e.g. "k0 fixed (physics)" or "full"
    reason: str  # one line: what the data showed and what was assumed
    voltage_span_v: float
    fixed: tuple[str, ...] = ()  # coefficients set by physics, not fitted
    evidence: dict[str, float] = field(default_factory=dict)  # figures behind the choice
    limited_by: str = ""  # "voltage span", "points", "physical sense" (full fit rejected), ""
    scaling: str = ""  # what the map's voltage scaling rests on

    def to_dict(self) -> dict[str, object]:
        return {
            **({"voltage_scaling": self.scaling} if self.scaling else {}),
            "form": self.form,
            "reason": self.reason,
            "voltage_span_v": self.voltage_span_v,
            "fixed": list(self.fixed),
            "evidence": dict(self.evidence),
            "limited_by": self.limited_by,
        }


def _term_name(i: int, j: int) -> str:
    parts = []
    if i:
        parts.append("T" if i == 1 else f"T^{i}")
    if j:
        parts.append("B" if j == 1 else f"B^{j}")
    return "*".join(parts) or "1"


_LETTERS = "abcdefghijklmnopqrstuvwxyz"


@dataclass(frozen=True)
class PolyModel(Model):
    """A polynomial surface in T and B given by its monomials T^i·B^j."""

    powers: tuple[tuple[int, int], ...] = ()

    def design(self, thrust_n: FloatArray, voltage_v: FloatArray) -> FloatArray:
        return np.stack([thrust_n**i * voltage_v**j for i, j in self.powers], axis=1)

    def _scaling(self, t: FloatArray, b: FloatArray) -> tuple[float, float, float]:
        ts = float(np.max(np.abs(t))) or 1.0
        bc = float(np.mean(b)) if self.uses_voltage else 0.0
        bs = float(np.std(b)) if self.uses_voltage else 1.0
        return ts, bc, bs or 1.0

    def conditioned(
        self, thrust_n: FloatArray, voltage_v: FloatArray
    ) -> tuple[FloatArray, Callable[[FloatArray], FloatArray]]:
        ts, bc, bs = self._scaling(thrust_n, voltage_v)
        design = self.design(thrust_n / ts, (voltage_v - bc) / bs)
        return design, lambda c: self._unscale(np.asarray(c, float), ts, bc, bs)

    def _unscale(self, c: FloatArray, ts: float, bc: float, bs: float) -> FloatArray:
        """Expand Σ c_ij (T/ts)^i ((B-bc)/bs)^j into the raw monomials T^i B^k."""
        index = {p: n for n, p in enumerate(self.powers)}
        raw = np.zeros(len(self.powers))
        for (i, j), cij in zip(self.powers, c, strict=True):
            for k in range(j + 1):
                weight = math.comb(j, k) * (-bc) ** (j - k) / (ts**i * bs**j)
                raw[index[(i, k)]] += cij * weight
        return raw


@dataclass(frozen=True)
class FeatureModel(Model):
    """A model given by explicit feature functions (physics-informed forms)."""

    features: Features | None = None

    def design(self, thrust_n: FloatArray, voltage_v: FloatArray) -> FloatArray:
        assert self.features is not None
        return self.features(thrust_n, voltage_v)


@dataclass(frozen=True)
class LinearTmaxModel(Model):
    """The seed paper's LA: Th = 100 % · T / Tmax, Tmax from a full-throttle point."""

    linear_least_squares = False

    def design(self, thrust_n: FloatArray, voltage_v: FloatArray) -> FloatArray:
        return np.asarray(thrust_n, float)[:, None]

    def fit(
        self, thrust_n: FloatArray, voltage_v: FloatArray, throttle_pct: FloatArray, loss: Loss
    ) -> FloatArray:
        full = throttle_pct >= 99.0
        if full.any():
            tmax = float(np.mean(thrust_n[full]))
        else:
            # No full-throttle plateau recorded: extrapolate the physics model to 100 %.
            coef = MODELS["motor"].fit(thrust_n, voltage_v, throttle_pct, loss)
            tmax = float(motor_forward(coef, np.array([100.0]), np.array([np.mean(voltage_v)]))[0])
        if not tmax > 0:
            raise FitError("linear Th = T/Tmax needs a positive full-throttle thrust")
        return np.array([100.0 / tmax])


def _poly_powers(degree: int) -> tuple[tuple[int, int], ...]:
    return tuple((i, d - i) for d in range(degree + 1) for i in range(d, -1, -1))


def _poly(name: str, powers: Sequence[tuple[int, int]], description: str) -> PolyModel:
    names = tuple(_term_name(i, j) for i, j in powers)
    formula = "Th = " + " + ".join(
        _LETTERS[n] + ("" if t == "1" else "*" + t) for n, t in enumerate(names)
    )
    return PolyModel(
        name=name,
        formula=formula,
        description=description,
        term_names=names,
        uses_voltage=any(j for _, j in powers),
        powers=tuple(powers),
    )


def _motor_features(t: FloatArray, b: FloatArray) -> FloatArray:
    tt = np.clip(t, 0.0, None)
    return np.stack([np.ones_like(t), 1.0 / b, np.sqrt(tt) / b, tt / b], axis=1)


#: relative voltage span (max − min over mean) below which k0 cannot be told from c
MIN_RELATIVE_SPAN = 0.05
#: points per coefficient needed before k0 is fitted (below, c and k0/B trade off freely)
MIN_POINTS_PER_COEFFICIENT = 8
#: a coefficient within this relative distance of a bound is on it (the solver stops there)
BOUND_TOLERANCE = 1e-6


#: no point's command cell exceeds this share of the commanded span (a ten-step staircase): one
#: stray point far from the rest must not outweigh the sweep
MAX_CELL_SHARE = 0.1
#: commands closer than this (% throttle) are one command when weighing points
COMMAND_RESOLUTION_PCT = 1e-3


#: a file whose points stand at one command counts for this span (% throttle) when files are
#: weighed by the range each covers
MIN_FILE_SPAN_PCT = 1.0


def command_weights(throttle_pct: FloatArray, groups: IntArray | None = None) -> FloatArray:
    """Each point's share of the command range it stands for (mean 1; see
    ``range_weights``). With ``groups`` (each point's file), every file covers its own range:
    its points share its span, and a file counts for the span it covers, so a slow ramp's
    thousand samples in one file cannot shrink a staircase's plateaus in another to one
    sample's worth each (issue 44: "44 plateaus carry 0 %"; held out by file the map is as
    good or better, see benchmarks/bench_weighting.py)."""
    th = np.asarray(throttle_pct, float)
    if groups is None or len(groups) != len(th):
        return range_weights(th)
    # file indices are small and non-negative: counted, not hashed (np.unique over a million
    # samples cost ~5 ms a call, and every fold weighs its points again)
    present = (
        np.flatnonzero(np.bincount(groups))
        if len(groups) and int(np.min(groups)) >= 0
        else np.unique(groups)
    )
    if len(present) < 2:
        return range_weights(th)
    w = np.zeros(len(th))
    for g in present:
        sel = groups == g
        span = max(float(np.ptp(th[sel])), MIN_FILE_SPAN_PCT)
        w[sel] = range_weights(th[sel]) * span / int(sel.sum())
    return np.asarray(w / float(np.mean(w)), dtype=float)


def range_weights(throttle_pct: FloatArray) -> FloatArray:
    """Each point's share of the command range it stands for (mean 1), so that the fit meets
    the map over the range a user commands rather than where the sweep lingered: a slow ramp
    leaves a hundred samples over a few percent of throttle, a staircase one plateau per step,
    and unweighted the ramp outvotes the plateaus (samples close in command are close in time
    on a sweep, so their errors are not independent either). A point's cell reaches halfway to
    its neighbours in throttle (the end points mirror theirs), points at one command share its
    cell, and no cell exceeds ``MAX_CELL_SHARE`` of the span."""
    th = np.asarray(throttle_pct, float)
    if len(th) < 2 or not np.all(np.isfinite(th)):
        return np.ones_like(th)
    # commands within COMMAND_RESOLUTION_PCT are one command; counted, not sorted (a million
    # raw samples take a few ms, and validation weighs every fold)
    keys = np.rint((th - float(np.min(th))) / COMMAND_RESOLUTION_PCT).astype(np.int64)
    if int(np.max(keys)) < 8 * len(keys) + 1_000_000:
        counts_all = np.bincount(keys)
        present = np.flatnonzero(counts_all)
        levels = present * COMMAND_RESOLUTION_PCT
        counts = counts_all[present]
        slot = np.zeros(len(counts_all), np.int64)
        slot[present] = np.arange(len(present))
        inverse = slot[keys]
    else:
        ukeys, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
        levels = ukeys * COMMAND_RESOLUTION_PCT
    if len(levels) < 2:
        return np.ones_like(th)
    gaps = np.diff(levels)
    cell = np.r_[gaps[0], (gaps[1:] + gaps[:-1]) / 2, gaps[-1]]
    cell = np.minimum(cell, MAX_CELL_SHARE * float(levels[-1] - levels[0]))
    w = (cell / counts)[inverse]
    return np.asarray(w / float(np.mean(w)), dtype=float)


#: the ESC's throttle offset (where its duty reaches zero), % of the range: an ESC whose duty is
#: a fifth of full at zero command, or that stays off over half its range, is not a motor's ESC
OFFSET_RANGE_PCT = (-20.0, 50.0)

SCALING_PHYSICS = "1/B from motor physics (duty × voltage sets speed; k0 = R·I0 ≈ 0 assumed)"
SCALING_FITTED = "1/B with the no-load term k0 fitted from the data's voltage spread"


@dataclass(frozen=True)
class MotorModel(FeatureModel):
    """``motor``, physical by construction: k0, k1, k2 ≥ 0 (so throttle rises with thrust and
    does not rise with voltage anywhere T ≥ 0) and the ESC offset c within ``OFFSET_RANGE_PCT``;
    fitted with k0 = 0 (physics) unless the data identifies k0 (see module doc)."""

    voltage_from_physics = True

    def _fit_form(
        self,
        t: FloatArray,
        b: FloatArray,
        th: FloatArray,
        loss: Loss,
        full: bool,
        *,
        free_offset: bool = False,
        groups: IntArray | None = None,
    ) -> FloatArray:
        """The bounded fit in the raw basis (the solver scales columns itself): k0 fitted
        (``full``) or held at 0; ``free_offset`` frees the offset c of its band."""
        design = self.design(t, b)
        lower, upper = self.lower(), self.upper()
        assert lower is not None and upper is not None
        keep = [0, 1, 2, 3] if full else [0, 2, 3]
        if free_offset:
            lower, upper = lower.copy(), upper.copy()
            lower[0], upper[0] = -np.inf, np.inf
        coef = np.zeros(4)
        coef[keep] = solve(
            design[:, keep],
            th,
            loss=loss,
            lower=lower[keep],
            upper=upper[keep],
            weights=self.fit_weights(th, groups),
        )
        return coef

    def _free_fit(
        self, t: FloatArray, b: FloatArray, th: FloatArray, loss: Loss, groups: IntArray | None
    ) -> FloatArray:
        """What the data alone say: c and k0 unconstrained (k1, k2 ≥ 0), for the report."""
        design = self.design(t, b)
        lower = np.array([-np.inf, -np.inf, 0.0, 0.0])
        return solve(design, th, loss=loss, lower=lower, weights=self.fit_weights(th, groups))

    def fit_weights(
        self, throttle_pct: FloatArray, groups: IntArray | None = None
    ) -> FloatArray | None:
        return command_weights(throttle_pct, groups)

    def _physics_reason(self, b: FloatArray) -> tuple[str, str] | None:
        """What the data lacks to identify k0 and the one-line reason (None: k0 is fitted)."""
        span = float(np.ptp(b)) if len(b) else 0.0
        mean_b = float(np.mean(b)) if len(b) else 0.0
        rel = span / mean_b if mean_b > 0 else 0.0
        physics = "1/B scaling from motor physics (k0 = R·I0 ≈ 0, c = ESC throttle offset)"
        if rel < MIN_RELATIVE_SPAN:
            return "voltage span", (
                f"voltage span {span:.2f} V ({100 * rel:.1f} % of {mean_b:.2f} V): {physics}, "
                "not fitted"
            )
        need = MIN_POINTS_PER_COEFFICIENT * self.n_coefficients
        if len(b) < need:
            return "points", (
                f"voltage span {span:.2f} V but only {len(b)} points (k0 and c need {need}+ to "
                f"be told apart): {physics}, not fitted"
            )
        return None

    def on_bound(self, coef: FloatArray, skip: Sequence[int] = ()) -> str:
        """Which coefficient ended on its physical bound ('' when none), e.g. 'c on its bound
        -20 %'. A coefficient there is not identified by the data: the bound chose it."""
        lower, upper = self.lower(), self.upper()
        assert lower is not None and upper is not None
        for i in range(self.n_coefficients):
            if i in skip:
                continue
            for bound in (lower[i], upper[i]):
                if np.isfinite(bound) and abs(coef[i] - bound) <= BOUND_TOLERANCE * (
                    1.0 + abs(bound)
                ):
                    label = "c" if i == 0 else ("k0", "k1", "k2")[i - 1]
                    unit = " %" if i == 0 else ""
                    return f"{label} on its bound {bound:g}{unit}"
        return ""

    def released_fit(
        self,
        t: FloatArray,
        b: FloatArray,
        th: FloatArray,
        loss: Loss,
        coef: FloatArray,
        groups: IntArray | None = None,
    ) -> FloatArray:
        """``coef``'s form refitted with the offset c free of its band (k0 stays 0 if it was):
        what the data would say without the bound, for the interval's bound term."""
        return self._fit_form(t, b, th, loss, coef[1] != 0.0, free_offset=True, groups=groups)

    def physics_fit(
        self,
        t: FloatArray,
        b: FloatArray,
        th: FloatArray,
        loss: Loss,
        reason: str,
        limit: str,
        evidence: dict[str, float] | None = None,
        groups: IntArray | None = None,
    ) -> tuple[FloatArray, Identification]:
        """The physics prior: k0 = 0 (1/B scaling), c, k1, k2 fitted within their bounds."""
        coef = self._fit_form(t, b, th, loss, False, groups=groups)
        span = float(np.ptp(b)) if len(b) else 0.0
        return coef, Identification(
            "k0 fixed (physics)",
            reason,
            span,
            ("1/B",),
            dict(evidence or {}),
            limit,
            SCALING_PHYSICS,
        )

    def free_columns(self, thrust_n: FloatArray, voltage_v: FloatArray) -> list[int]:
        return [0, 2, 3] if self._physics_reason(voltage_v) is not None else [0, 1, 2, 3]

    def identify(
        self,
        thrust_n: FloatArray,
        voltage_v: FloatArray,
        throttle_pct: FloatArray,
        loss: Loss,
        groups: IntArray | None = None,
    ) -> tuple[FloatArray, Identification | None]:
        t, b, th, g = thrust_n, voltage_v, throttle_pct, groups
        span = float(np.ptp(b)) if len(b) else 0.0
        lacking = self._physics_reason(b)
        if lacking is not None:
            limit, reason = lacking
            evidence = {"points": float(len(b)), "relative_voltage_span": span / float(np.mean(b))}
            return self.physics_fit(t, b, th, loss, reason, limit, evidence, g)
        mean_b = float(np.mean(b))
        free = self._free_fit(t, b, th, loss, g)
        unphysical = _unphysical(free, t)
        coef = self._fit_form(t, b, th, loss, True, groups=g)
        on_bound = self.on_bound(coef, skip=(1, 2, 3))  # c trades off with k0/B
        if on_bound:
            why = f"fitting k0 freely gave {unphysical}; " if unphysical else ""
            reason = (
                f"voltage span {span:.2f} V over {len(b)} points, but {why}the bounded fit ended "
                f"with {on_bound} (k0 = {coef[1]:.3g}): not identified, the physics prior "
                "(k0 = 0) is used"
            )
            return self.physics_fit(
                t,
                b,
                th,
                loss,
                reason,
                "physical sense" if unphysical else "bound",
                {"bounded_c_pct": float(coef[0]), "bounded_k0": float(coef[1])},
                g,
            )
        if unphysical:
            k0_zero = coef[1] <= 0.0
            kept = (
                "1/B scaling from motor physics (k0 = 0) kept"
                if k0_zero
                else f"fitted within physics (k0 = {coef[1]:.3g} ≥ 0, c = {coef[0]:.1f} % in "
                f"{OFFSET_RANGE_PCT[0]:g}..{OFFSET_RANGE_PCT[1]:g} %)"
            )
            reason = (
                f"voltage span {span:.2f} V over {len(b)} points, but fitting k0 freely gave "
                f"{unphysical}: {kept}"
            )
            return coef, Identification(
                "k0 fixed (physics)" if k0_zero else "full",
                reason,
                span,
                ("1/B",) if k0_zero else (),
                {"free_c_pct": float(free[0]), "free_k0": float(free[1])},
                "physical sense",
                SCALING_PHYSICS if k0_zero else SCALING_FITTED,
            )
        reason = (
            f"voltage span {span:.2f} V ({100 * span / mean_b:.1f} % of {mean_b:.2f} V) over "
            f"{len(b)} points: 1/B term fitted from the data"
        )
        return coef, Identification("full", reason, span, scaling=SCALING_FITTED)


def _unphysical(coef: FloatArray, thrust_n: FloatArray) -> str:
    """Why a free ``motor`` fit cannot be a motor ('' when it can): the throttle offset outside
    its band, or a negative no-load term k0 (then throttle rises with voltage at low thrust,
    and the voltage slices cross)."""
    c, k0, k1, k2 = (float(x) for x in coef)
    if not OFFSET_RANGE_PCT[0] <= c <= OFFSET_RANGE_PCT[1]:
        return (
            f"a throttle offset c = {c:.1f} % (outside {OFFSET_RANGE_PCT[0]:g}.."
            f"{OFFSET_RANGE_PCT[1]:g} %)"
        )
    if k0 < 0:
        # where k0 + k1·√T + k2·T crosses zero: below it more voltage would need more throttle
        s = (
            (-k1 + math.sqrt(k1 * k1 - 4 * k2 * k0)) / (2 * k2)
            if k2 > 0
            else (-k0 / k1 if k1 > 0 else math.inf)
        )
        t_top = float(np.max(thrust_n)) if len(thrust_n) else 0.0
        below = (
            f"below {s * s:.3g} N"
            if math.isfinite(s) and s * s < t_top
            else "over the whole thrust range"
        )
        return (
            f"k0 = {k0:.1f}, c = {c:.1f} % (a negative no-load term: throttle rising with "
            f"voltage {below})"
        )
    return ""


SCALING_BACKEMF = (
    "1/B from back-EMF and winding loss measured by the stand (B·d = Ke·ω + R·I from the "
    "logged rpm and current)"
)
#: fewest spinning rows with rpm and current before the back-EMF scaling is tried
MIN_BACKEMF_ROWS = 8


def backemf_coefficients(
    throttle_pct: FloatArray,
    thrust_n: FloatArray,
    voltage_v: FloatArray,
    rpm: FloatArray,
    current_a: FloatArray,
) -> FloatArray | None:
    """``motor`` coefficients identified from the stand's rpm and current rather than assumed.

    The ESC's duty d = (Th − c)/100 drives B·d = Ke·ω + R·I (back-EMF and winding loss), so
    Th = c + a·ω/B + r·I/B is fitted on the spinning rows (a = 100·Ke, r = 100·R ≥ 0, c in its
    band). The propeller fixes ω(T) = w1·√T + w2·T and the motor I(T) = i0 + i1·√T + i2·T
    (all ≥ 0, voltage-free), so the map is Th = c + (r·i0 + (a·w1 + r·i1)·√T + (a·w2 + r·i2)·T)/B:
    the ``motor`` form with k0 = R·I0 measured, physical by construction. None when the rows
    cannot support it (too few spinning rows with rpm and current)."""
    w = np.abs(np.asarray(rpm, float))
    i = np.abs(np.asarray(current_a, float))
    t = np.asarray(thrust_n, float)
    b = np.asarray(voltage_v, float)
    th = np.asarray(throttle_pct, float)
    ok = np.isfinite(w) & np.isfinite(i) & np.isfinite(t) & np.isfinite(b) & np.isfinite(th)
    if not ok.any():
        return None
    ok &= (w > 0.02 * float(np.max(w[ok]))) & (t > 0) & (b > 0)
    if int(ok.sum()) < MIN_BACKEMF_ROWS:
        return None
    w, i, t, b, th = w[ok], i[ok], t[ok], b[ok], th[ok]
    try:
        c, a, r = solve(
            np.stack([np.ones_like(b), w / b, i / b], axis=1),
            th,
            lower=np.array([OFFSET_RANGE_PCT[0], 0.0, 0.0]),
            upper=np.array([OFFSET_RANGE_PCT[1], np.inf, np.inf]),
        )
        st = np.sqrt(t)
        w1, w2 = solve(np.stack([st, t], axis=1), w, lower=np.zeros(2))
        i0, i1, i2 = solve(np.stack([np.ones_like(t), st, t], axis=1), i, lower=np.zeros(3))
    except FitError:
        return None
    coef = np.array([c, r * i0, a * w1 + r * i1, a * w2 + r * i2], dtype=float)
    return coef if np.all(np.isfinite(coef)) else None


def motor_forward(
    coefficients: npt.ArrayLike, throttle_pct: FloatArray, voltage_v: FloatArray
) -> FloatArray:
    """Closed-form inverse of ``motor``: thrust from throttle (solve the quadratic in √T)."""
    c, k0, k1, k2 = (float(x) for x in np.asarray(coefficients, float))
    rhs = (np.asarray(throttle_pct, float) - c) * np.asarray(voltage_v, float) - k0
    if k2 > 0:
        s = (-k1 + np.sqrt(np.clip(k1 * k1 + 4 * k2 * rhs, 0.0, None))) / (2 * k2)
    else:
        s = rhs / k1 if k1 > 0 else np.zeros_like(rhs)
    return np.asarray(np.clip(s, 0.0, None) ** 2, dtype=float)


_PAPER_TRUNC2 = ((0, 0), (1, 0), (0, 1), (2, 0))
_PAPER_TRUNC3 = ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2), (0, 3))

MODELS: dict[str, Model] = {
    m.name: m
    for m in (
        LinearTmaxModel(
            name="la",
            formula="Th = 100 * T / Tmax",
            description="seed paper LA: linear through zero, Tmax from a full-throttle point",
            term_names=("T",),
            uses_voltage=False,
        ),
        _poly("linear", ((0, 0), (1, 0)), "linear in thrust, no voltage (seed paper eq. 5)"),
        _poly("poly1", _poly_powers(1), "full bivariate polynomial, degree 1"),
        _poly("poly2", _poly_powers(2), "full bivariate polynomial, degree 2 (seed paper eq. 12)"),
        _poly("poly3", _poly_powers(3), "full bivariate polynomial, degree 3"),
        _poly("poly4", _poly_powers(4), "full bivariate polynomial, degree 4"),
        _poly("poly2-trunc", _PAPER_TRUNC2, "seed paper's 2nd-degree truncated form"),
        _poly("poly3-trunc", _PAPER_TRUNC3, "seed paper's 3rd-degree truncated form"),
        MotorModel(
            name="motor",
            formula="Th = c + (k0 + k1*sqrt(T) + k2*T) / B,  k0, k1, k2 >= 0, -20 <= c <= 50",
            description="physics-informed: duty x voltage drives rotor speed, thrust ~ speed^2; "
            "rises with T and never with B by construction; k0 = 0 unless the data spans "
            "enough voltage to fit it",
            term_names=("1", "1/B", "sqrt(T)/B", "T/B"),
            uses_voltage=True,
            lower_bounds=(OFFSET_RANGE_PCT[0], 0.0, 0.0, 0.0),
            upper_bounds=(OFFSET_RANGE_PCT[1], np.inf, np.inf, np.inf),
            features=_motor_features,
        ),
    )
}

if tuple(MODELS) != MODEL_NAMES:  # the names the CLI offers must be the ones implemented
    raise ImportError(f"fitting.names.MODEL_NAMES {MODEL_NAMES} != MODELS {tuple(MODELS)}")


def get_model(name: str) -> Model:
    try:
        return MODELS[name]
    except KeyError:
        raise ConfigError(f"unknown model '{name}'; expected one of: {', '.join(MODELS)}") from None
