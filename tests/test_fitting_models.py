"""Models and solvers: exact recovery, exact L1, monotone physics model, forward = inverse⁻¹."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from thrustmap.core.units import SCALES
from thrustmap.fitting.mapfile import Box, ThrustMap, ValidityBox
from thrustmap.fitting.models import MODELS, PolyModel, motor_forward
from thrustmap.fitting.solve import solve


def grid(n: int = 400, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.uniform(0.2, 10.0, n), rng.uniform(20.4, 25.2, n)


@pytest.mark.parametrize("name", [n for n, m in MODELS.items() if isinstance(m, PolyModel)])
def test_polynomials_recover_raw_coefficients_exactly(name: str) -> None:
    m = MODELS[name]
    rng = np.random.default_rng(7)
    true = rng.normal(size=m.n_coefficients) * np.array([10.0 ** -(i + j) for i, j in m.powers])  # type: ignore[attr-defined]
    t, b = grid()
    th = m.evaluate(true, t, b)
    got = m.fit(t, b, th, "l2")
    np.testing.assert_allclose(m.evaluate(got, t, b), th, atol=1e-8)
    np.testing.assert_allclose(got, true, rtol=1e-5, atol=1e-9)


def test_l1_is_the_exact_lad_optimum() -> None:
    rng = np.random.default_rng(3)
    x = rng.uniform(0, 10, 60)
    a = np.stack([np.ones_like(x), x], axis=1)
    y = 2.0 + 0.5 * x + rng.standard_t(1.5, size=x.size)
    c = solve(a, y, loss="l1")
    best = np.abs(a @ c - y).sum()
    # An L1 optimum passes through (at least) two data points: brute force over all pairs.
    brute = min(
        np.abs(a @ np.linalg.solve(a[[i, j]], y[[i, j]]) - y).sum()
        for i in range(60)
        for j in range(i + 1, 60)
        if abs(x[i] - x[j]) > 1e-9
    )
    assert best == pytest.approx(brute, rel=1e-9, abs=1e-9)
    # and it is robust: a gross outlier barely moves it while least squares follows it
    y2 = y.copy()
    y2[0] += 1000
    assert np.abs(solve(a, y2, loss="l1") - c).max() < 0.05
    assert np.abs(solve(a, y2, loss="l2") - solve(a, y, loss="l2")).max() > 1.0


def test_motor_model_stays_monotone_even_on_noisy_data() -> None:
    m = MODELS["motor"]
    t, b = grid(300)
    rng = np.random.default_rng(0)
    th = 5 + (40 + 60 * np.sqrt(t) + 25 * t) / b + rng.normal(0, 3, t.size)
    coef = m.fit(t, b, th, "l2")
    assert coef[2] >= 0 and coef[3] >= 0
    tt = np.linspace(0, 12, 500)
    for volt in (18.0, 22.0, 26.0):  # including outside the fitted voltage range
        assert np.all(np.diff(m.evaluate(coef, tt, np.full_like(tt, volt))) >= 0)


@settings(max_examples=50, deadline=None)
@given(th=st.floats(10, 95), volt=st.floats(20, 25))
def test_motor_forward_inverts_the_map(th: float, volt: float) -> None:
    coef = np.array([3.0, 40.0, 150.0, 30.0])
    t = motor_forward(coef, np.array([th]), np.array([volt]))
    assert MODELS["motor"].evaluate(coef, t, np.array([volt]))[0] == pytest.approx(th, abs=1e-9)


@pytest.mark.parametrize("name", ["poly2", "poly3-trunc", "linear"])
def test_map_forward_bisection_inverts_polynomial(name: str) -> None:
    m = MODELS[name]
    t, b = grid()
    th = 100 * np.sqrt(t / 12.0) * (22.0 / b) ** 0.5
    coef = m.fit(t, b, th, "l2")
    box = ValidityBox(Box(0.2, 10.0), Box(20.4, 25.2), Box(0, 100))
    tmap = ThrustMap(
        model=name, coefficients=tuple(coef), throttle_scale=SCALES["pwm"], validity=box
    )
    tq = np.array([1.0, 4.0, 8.0])
    bq = np.array([21.0, 22.5, 24.0])
    np.testing.assert_allclose(tmap.thrust_n(tmap.throttle_pct(tq, bq), bq), tq, rtol=1e-9)


def test_motor_validation_fast_path_matches_per_fold_fits() -> None:
    """By-file validation reuses one design; with k0 fixed by physics in some folds and fitted
    in others it must give exactly what fitting each fold separately gives."""
    from thrustmap.fitting.fit.coefficients import Pool, fit_coefficients
    from thrustmap.fitting.fit.validation import validate

    rng = np.random.default_rng(2)
    parts = []
    for f, (b0, n) in enumerate(((22.0, 40), (24.5, 40), (7.4, 12))):
        t = rng.uniform(0.3, 8.0, n)
        b = b0 - 0.3 * rng.uniform(0, 1, n)
        th = 4 + (30 + 60 * np.sqrt(t) + 25 * t) / b + rng.normal(0, 0.3, n)
        parts.append((t, b, th, np.full(n, f, dtype=np.int64)))
    t, b, th, fi = (np.concatenate(x) for x in zip(*parts, strict=True))
    data = Pool(t, b, th, fi, (None, None, None), SCALES["pwm"])  # type: ignore[arg-type]
    row = validate(data, "motor", "by-file")
    m = MODELS["motor"]
    errs = []
    for f in range(3):
        tr, te = fi != f, fi == f
        coef = fit_coefficients(m, t[tr], b[tr], th[tr], "l2")
        errs.append(np.abs(m.evaluate(coef, t[te], b[te]) - th[te]))
    assert row.all.mean_pct == pytest.approx(float(np.concatenate(errs).mean()), rel=1e-6)


@pytest.mark.parametrize("loss", ["l2", "l1"])
def test_solve_weight_two_is_the_row_counted_twice(loss: str) -> None:
    rng = np.random.default_rng(3)
    x = np.column_stack([np.ones(30), rng.uniform(0, 5, 30), rng.uniform(0, 5, 30)])
    y = x @ np.array([1.0, 2.0, -0.5]) + rng.normal(0, 0.5, 30)
    w = np.ones(30)
    w[:7] = 2.0
    doubled = solve(np.vstack([x, x[:7]]), np.r_[y, y[:7]], loss=loss)  # type: ignore[arg-type]
    weighted = solve(x, y, loss=loss, weights=w)  # type: ignore[arg-type]
    np.testing.assert_allclose(weighted, doubled, rtol=1e-6, atol=1e-6)


def test_command_weights_give_each_point_its_share_of_the_range() -> None:
    from thrustmap.fitting.models import command_weights

    # a slow ramp leaves 100 samples over 10..12 %, a staircase one plateau at 30, 50 and 70 %
    th = np.r_[np.linspace(10.0, 12.0, 100), 30.0, 50.0, 70.0]
    w = command_weights(th)
    assert w.mean() == pytest.approx(1.0)
    assert w[100:].sum() > 2 * w[:100].sum()  # three plateaus outweigh the hundred samples
    np.testing.assert_allclose(w[100:], w[100])  # each capped at a tenth of the span
    # points at one command share its cell; a uniform staircase weighs its steps equally
    shared = command_weights(np.array([10.0, 10.0, 20.0, 30.0]))
    np.testing.assert_allclose(shared / shared[2], [0.5, 0.5, 1, 1])
    np.testing.assert_allclose(command_weights(np.arange(10.0, 100.0, 10.0)), 1.0)
    np.testing.assert_allclose(command_weights(np.array([42.0, 42.0])), 1.0)


def test_motor_fit_is_not_outvoted_by_a_slow_ramps_samples() -> None:
    """The same sweep with a slow ramp's samples densified tenfold gives the same map: the fit
    meets the data over the commanded range, not where the sweep lingered (the xNova 'steps'
    file: 29 of its 38 points lie between 10 and 20 % throttle)."""
    m = MODELS["motor"]
    volt = 22.0

    def true_th(t: np.ndarray) -> np.ndarray:  # a real ESC's curve is not exactly the form
        u = (40 * np.sqrt(t) + 90 * t) / volt
        return 3 + u + 1.5 * np.sin(u / 12)

    t_steps = np.linspace(0.5, 9.0, 9)

    def fitted(n_ramp: int) -> np.ndarray:
        t = np.r_[np.linspace(0.05, 0.5, n_ramp), t_steps]
        th = true_th(t)
        return m.fit(t, np.full(len(t), volt), th, "l2")

    tq = np.linspace(0.05, 9.0, 50)
    bq = np.full(50, volt)
    sparse, dense = (m.evaluate(fitted(n), tq, bq) for n in (10, 100))
    assert float(np.max(np.abs(dense - sparse))) < 0.15
    truth = true_th(tq)
    assert float(np.mean(np.abs(dense - truth))) < 0.5


def test_fit_says_how_the_weight_was_shared() -> None:
    from thrustmap.fitting.fit.coefficients import Pool
    from thrustmap.fitting.fit.fitmap import weighting_line
    from thrustmap.fitting.selection.points import Points

    def points(th: np.ndarray, kind: str) -> Points:
        t = (th / 100.0) ** 2 * 8.0
        return Points("f.csv", t, np.full(len(th), 22.0), th, np.full(len(th), kind))

    def pool(*parts: Points) -> Pool:
        cat = [np.concatenate([getattr(p, a) for p in parts]) for a in ("thrust_n", "voltage_v")]
        th = np.concatenate([p.throttle_pct for p in parts])
        fi = np.zeros(len(th), dtype=np.int64)
        return Pool(cat[0], cat[1], th, fi, parts, SCALES["pwm"])

    ramp = points(np.linspace(10.0, 12.0, 50), "ramp")
    steps = points(np.array([30.0, 40.0, 50.0, 60.0]), "plateau")
    line = weighting_line(MODELS["motor"], pool(ramp, steps))
    assert line.startswith("fit weights:") and "50 ramp samples carry" in line
    share = int(line.split("4 plateaus carry ")[1].split(" %")[0])
    assert share > 50  # four plateaus over 30-60 % outweigh fifty samples over 10-12 %
    # evenly spaced steps weigh the same: nothing to say; an unweighted model says nothing
    even = points(np.arange(10.0, 100.0, 10.0), "step-summary")
    assert weighting_line(MODELS["motor"], pool(even)) == ""
    assert weighting_line(MODELS["poly2"], pool(ramp, steps)) == ""
