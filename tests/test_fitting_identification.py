"""The default model is identified by physics where the data cannot identify it (issue 12 item 3),
held-out figures count every point (item 4), maps carry a prediction interval (item 5)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from thrustmap.cli import main
from thrustmap.core.errors import FitError
from thrustmap.core.units import SCALES
from thrustmap.fitting.dataset import Dataset
from thrustmap.fitting.fit.fitmap import fit_map
from thrustmap.fitting.fit.validation import compare, evaluate
from thrustmap.fitting.loaders.load import load_datasets
from thrustmap.fitting.selection.options import Selection


def bldc_throttle_pct(
    thrust_n: np.ndarray, voltage_v: np.ndarray, *, kv: float = 2400.0, offset_pct: float = 4.0
) -> np.ndarray:
    """A BLDC motor and propeller from first principles (not the model's own form): the ESC's
    duty is (Th − offset)/(100 − offset); ω = Kv·(d·B − R·I); I = I0 + Q/Kt; Q = kq·ω²;
    T = kt·ω². Returns the throttle % that produces ``thrust_n`` at ``voltage_v``."""
    r_ohm, i0_a = 0.08, 0.6
    kv_rad = kv * 2 * np.pi / 60.0  # rad/s per V
    kt_nm_a = 1.0 / kv_rad
    kt = 2.5e-6 * (2400.0 / kv) ** 2  # N/(rad/s)², a 5-inch propeller
    kq = kt * 0.012
    omega = np.sqrt(thrust_n / kt)
    current = i0_a + kq * omega**2 / kt_nm_a
    duty = (omega / kv_rad + r_ohm * current) / voltage_v
    return np.asarray(offset_pct + (100.0 - offset_pct) * duty)


def step_summary(voltage_v: float, name: str, sag_ohm: float = 0.01) -> Dataset:
    """One averaged row per throttle step at a nominal supply voltage with a little sag."""
    thrust = np.linspace(0.15, 4.0, 11)
    sag = sag_ohm * thrust * 6.0  # ~ current × wiring resistance
    volts = voltage_v - sag
    th = bldc_throttle_pct(thrust, volts)
    return Dataset(
        path=name,
        format="synthetic",
        throttle_scale=SCALES["pwm"],
        throttle_native=SCALES["pwm"].from_pct(th),
        thrust_n=thrust,
        voltage_v=volts,
        line=np.arange(len(thrust), dtype=np.int64) + 2,
    )


ALL = Selection(all_samples=True)


@pytest.mark.parametrize(("train_v", "test_v"), [(7.4, 11.1), (11.1, 7.4), (14.8, 22.2)])
def test_one_voltage_fit_carries_across_voltage_by_physics(train_v: float, test_v: float) -> None:
    train = step_summary(train_v, "train.csv")
    test = step_summary(test_v, "test.csv")
    out = fit_map([train], selection=ALL)
    ident = out.map.identification
    assert ident["fixed"] == ["1/B"]
    assert "voltage span" in ident["reason"] and "not fitted" in ident["reason"]
    assert out.map.coefficients[1] == 0.0  # k0 set by physics
    (row,) = evaluate(out.map, [test], ALL)
    # every point of the other voltage is outside the box; the physics carries the map there
    assert row.all.n == 11 and row.inside.n == 0
    assert row.all.mean_pct < 1.5, row.all


def test_fit_with_no_voltage_spread_is_not_refused_for_the_default() -> None:
    flat = step_summary(7.4, "flat.csv", sag_ohm=0.0)
    out = fit_map([flat], selection=ALL)
    assert "not fitted" in out.map.identification["reason"]
    with pytest.raises(FitError, match="one battery voltage"):
        fit_map([flat], model="poly2", selection=ALL)


def discharge_sweeps(files: int = 3, levels: int = 20) -> list[Dataset]:
    """Sweeps over a real discharge: many points at several battery states."""
    out = []
    for f in range(files):
        thrust = np.tile(np.linspace(0.3, 8.0, levels), 2)
        volts = 25.0 - 1.5 * f - np.linspace(0, 0.8, thrust.size) - 0.05 * thrust
        th = bldc_throttle_pct(thrust, volts, kv=2100.0)
        out.append(
            Dataset(
                path=f"d{f}.csv",
                format="synthetic",
                throttle_scale=SCALES["pwm"],
                throttle_native=SCALES["pwm"].from_pct(th),
                thrust_n=thrust,
                voltage_v=volts,
                line=np.arange(thrust.size, dtype=np.int64) + 2,
            )
        )
    return out


def test_wide_span_but_few_points_keeps_physics_and_asks_for_more_levels() -> None:
    a = step_summary(7.4, "a.csv")
    b = step_summary(11.1, "b.csv")
    out = fit_map([a, b], selection=ALL)  # 22 points across 7–11 V
    assert out.map.identification["limited_by"] == "points"
    assert "more throttle levels at several voltages" in out.more_data


def test_wide_voltage_span_with_many_points_fits_the_voltage_term() -> None:
    out = fit_map(discharge_sweeps(), selection=ALL)
    assert out.map.identification["form"] == "full"
    assert "fitted from the data" in out.map.identification["reason"]
    assert out.map.identification["fixed"] == []


def test_a_full_fit_that_cannot_be_a_motor_is_not_used() -> None:
    """Data in which throttle RISES with voltage (lag or sag confounded with the battery, as in
    a badly selected staircase) must not turn into a map with an absurd offset and 1/B term."""
    from thrustmap.fitting.models import MODELS

    rng = np.random.default_rng(1)
    t = np.tile(np.linspace(0.3, 6.0, 20), 3)
    b = np.repeat([21.0, 22.5, 24.0], 20) + rng.normal(0, 0.05, 60)
    th = 5 + (400 * np.sqrt(t) + 30 * t) / b + 6.0 * (b - 22.5)
    coef, ident = MODELS["motor"].identify(t, b, th, "l2")
    assert ident is not None and ident.limited_by == "physical sense"
    assert "throttle offset" in ident.reason and coef[1] == 0.0
    # the map keeps the physical sign: more voltage, less throttle for the same thrust
    lo = MODELS["motor"].evaluate(coef, np.array([3.0]), np.array([21.0]))[0]
    hi = MODELS["motor"].evaluate(coef, np.array([3.0]), np.array([24.0]))[0]
    assert hi < lo
    # an offset inside the range, but throttle rising with voltage mid-range: also refused
    th2 = -20 + (100 * np.sqrt(t) + 5 * t) / b + 2.0 * (b - 22.5)
    coef2, ident2 = MODELS["motor"].identify(t, b, th2, "l2")
    assert ident2 is not None and ident2.limited_by == "physical sense"
    assert "throttle rising with voltage" in ident2.reason and coef2[1] == 0.0


def test_fit_cli_says_what_it_identified_and_where_to_trust(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    ds = step_summary(7.4, "x.csv")
    csv = tmp_path / "x.csv"
    lines = ["throttle,thrust,volts"] + [
        f"{a},{b},{c}"
        for a, b, c in zip(ds.throttle_native, ds.thrust_n, ds.voltage_v, strict=True)
    ]
    csv.write_text("\n".join(lines) + "\n")
    out_map = tmp_path / "m.json"
    args = ["--col-throttle", "throttle", "--col-thrust", "thrust", "--col-voltage", "volts"]
    main(["fit", str(csv), "-o", str(out_map), "--all-samples", *args])
    text = capsys.readouterr().out
    assert "identification: voltage span" in text and "not fitted" in text
    assert "trustworthy to ±" in text
    assert "more data would help most at another battery voltage" in text
    doc = json.loads(out_map.read_text())
    assert doc["identification"]["fixed"] == ["1/B"]
    assert doc["interval"]["half_width_pct"] > 0
    # predict: throttle ± interval, wider and warned outside the box
    main(["predict", str(out_map), "--thrust-n", "2.0", "--voltage-v", "7.35", "--json"])
    inside = json.loads(capsys.readouterr().out)
    main(["predict", str(out_map), "--thrust-n", "2.0", "--voltage-v", "11.1", "--json"])
    captured = capsys.readouterr()
    outside = json.loads(captured.out)
    assert inside["inside_validity_box"] and not outside["inside_validity_box"]
    assert 0 < inside["interval_pct"] < outside["interval_pct"]
    # a voltage distance only: its share is in the interval there (no "widened x1.00")
    assert "outside the map's supported region" in captured.err
    assert "the voltage distance included" in captured.err
    main(["predict", str(out_map), "--thrust-n", "2.0", "--voltage-v", "7.35"])
    assert " ± " in capsys.readouterr().out
    with pytest.raises(SystemExit) as exc:
        main(["predict", str(out_map), "--thrust-n", "nan", "--voltage-v", "7.35"])
    assert exc.value.code == 2
    assert "--thrust-n: expected a finite number" in capsys.readouterr().err


def test_interval_covers_held_out_points_and_widens_with_distance() -> None:
    data = discharge_sweeps()
    rng = np.random.default_rng(4)
    noisy = [
        Dataset(**{**d.__dict__, "throttle_native": d.throttle_native + rng.normal(0, 4, len(d))})
        for d in data
    ]
    out = fit_map(noisy[:2], selection=ALL)
    iv = out.map.prediction_interval()
    assert iv is not None
    (row,) = evaluate(out.map, [noisy[2]], ALL)
    half = iv.half_width(noisy[2].thrust_n, noisy[2].voltage_v)
    pred = out.map.throttle_pct(noisy[2].thrust_n, noisy[2].voltage_v)
    covered = np.abs(pred - noisy[2].throttle_pct) <= half
    assert covered.mean() >= 0.85, covered.mean()
    b_hi = out.map.validity.voltage_v.hi
    near = float(iv.half_width(4.0, b_hi))
    far = float(iv.half_width(4.0, b_hi + 5.0))
    assert far > near * 1.5


# -- held-out validation: every point is the headline, JSON has no NaN -------------------------


def test_rows_headline_counts_every_held_out_point_and_json_has_no_nan() -> None:
    a = step_summary(7.4, "a.csv")
    b = step_summary(11.1, "b.csv")
    (row,) = compare([a, b], ["motor"], "by-file", selection=ALL)
    assert row.all.n == 22 and row.inside.n == 0 and row.outside.n == 22
    d = row.to_dict()
    assert d["n"] == 22 and d["mean_pct"] == pytest.approx(row.all.mean_pct)
    assert d["inside_box"]["n"] == 0 and d["inside_box"]["mean_pct"] is None
    assert d["outside_box"]["n"] == 22
    json.dumps(d, allow_nan=False)  # raises on NaN


def test_compare_and_evaluate_json_parse_strictly(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    paths = []
    for v, name in ((7.4, "a.csv"), (11.1, "b.csv")):
        ds = step_summary(v, name)
        p = tmp_path / name
        p.write_text(
            "throttle,thrust,volts\n"
            + "\n".join(
                f"{x},{y},{z}"
                for x, y, z in zip(ds.throttle_native, ds.thrust_n, ds.voltage_v, strict=True)
            )
            + "\n"
        )
        paths.append(str(p))
    cols = ["--col-throttle", "throttle", "--col-thrust", "thrust", "--col-voltage", "volts"]

    def strict(text: str) -> dict[str, object]:
        def no_const(name: str) -> None:
            raise AssertionError(f"{name} in --json output")

        out: dict[str, object] = json.loads(text, parse_constant=no_const)
        return out

    main(["compare", *paths, "--models", "motor,linear", "--validate", "by-file", "--json",
          "--all-samples", *cols])  # fmt: skip
    rows = strict(capsys.readouterr().out)["rows"]
    assert all(r["n"] == 22 for r in rows)  # type: ignore[index, union-attr]
    m = tmp_path / "a.json"
    main(["fit", paths[0], "-o", str(m), "--all-samples", *cols])
    capsys.readouterr()
    main(["evaluate", str(m), paths[1], "--json", "--all-samples", *cols])
    (row,) = strict(capsys.readouterr().out)["rows"]  # type: ignore[misc]
    assert row["n"] == 11 and row["inside_box"]["mean_pct"] is None


# -- real data: other people's rigs, and the seed paper's ----------------------------------------

STRAWSON = "third-party-stands/strawson-5inch"


def _fit_eval(train: Dataset, test: Dataset) -> float:
    """Fit with defaults and score all points of the other file; before step-summary exports
    were accepted by the default selection, fall back to their rows (already steady points)."""
    try:
        out = fit_map([train])
        sel: Selection = Selection()
    except FitError as exc:
        if "no steady-state points" not in str(exc):
            raise
        out, sel = fit_map([train], selection=ALL), ALL
    try:
        (row,) = evaluate(out.map, [test], sel)
    except FitError:
        (row,) = evaluate(out.map, [test], ALL)
    return row.all.mean_pct


def test_strawson_cross_voltage_sample(shared_data: Path) -> None:
    """A sample of the development set (every motor, two propellers): 2S ↔ 3S."""
    folder = shared_data / STRAWSON
    errors = []
    for motor in "abcdef":
        for prop in "27":
            a, b = load_datasets(
                [str(folder / f"{motor}{prop}_7.csv"), str(folder / f"{motor}{prop}_11.csv")]
            )
            errors += [_fit_eval(a, b), _fit_eval(b, a)]
    assert len(errors) == 24
    assert np.median(errors) <= 3.0, errors
    assert np.percentile(errors, 90) <= 6.0, errors


def test_xnova_by_file_inside_and_all_points(
    shared_data: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sr = shared_data / "xnova-thrust-stand" / "single_rotor"
    main(["compare", str(sr / "xNova-SR-steps.csv"), str(sr / "xNova-SR-steps-up.csv"),
          "--models", "motor", "--validate", "by-file", "--json"])  # fmt: skip
    (row,) = json.loads(capsys.readouterr().out)["rows"]
    # physical maps (issue 18): these two files disagree with any motor's voltage dependence
    # (tests/test_fitting_paper.py), so the held-out floor is ~1.1 %, not the 0.5 % that a
    # negative no-load term bought by crossing the voltage slices
    assert row["inside_box"]["mean_pct"] <= 1.2
    assert row["n"] == row["inside_box"]["n"] + row["outside_box"]["n"]
    assert row["mean_pct"] <= 1.15  # all held-out points, the headline
