"""Physical maps by construction (issue 18, item 1): the default map rises with thrust and never
with voltage over its supported region, has no negative no-load term and a plausible ESC
offset, on every stand file of the shared data and on data built to tempt it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from thrustmap.cli import main
from thrustmap.fitting.fit.fitmap import fit_map
from thrustmap.fitting.loaders.load import load_datasets
from thrustmap.fitting.mapfile import ThrustMap
from thrustmap.fitting.models import MODELS, OFFSET_RANGE_PCT


def assert_physical(tmap: ThrustMap, where: str) -> None:
    c, k0, k1, k2 = tmap.coefficients
    assert k0 >= 0 and k1 >= 0 and k2 >= 0, (where, tmap.coefficients)
    assert OFFSET_RANGE_PCT[0] <= c <= OFFSET_RANGE_PCT[1], (where, c)
    tt, bb = tmap.supported_region().grid(60)  # rows: one voltage each, thrust ascending
    th = tmap.throttle_pct(tt, bb, corrected=False)
    assert (np.diff(th, axis=1) >= -1e-9).all(), f"{where}: not monotone in thrust"
    # in voltage: the same thrusts at rising voltages
    t_lo, t_hi = float(tt.min()), float(tt.max())
    b = np.linspace(float(bb.min()), float(bb.max()), 40)
    tg, bg = np.meshgrid(np.linspace(t_lo, t_hi, 60), b)
    inside = tmap.supported_region().contains(tg, bg)
    thg = tmap.throttle_pct(tg, bg, corrected=False)
    rises = (np.diff(thg, axis=0) > 1e-9) & inside[1:] & inside[:-1]
    assert not rises.any(), f"{where}: throttle rises with voltage"


def stand_files(root: Path) -> list[Path]:
    files = sorted((root / "xnova-thrust-stand").glob("*/*.csv"))
    files += sorted((root / "third-party-stands").glob("*/*.csv"))
    return files


def test_default_map_is_physical_on_every_shared_stand_file(shared_data: Path) -> None:
    files = stand_files(shared_data)
    assert len(files) >= 100
    for f in files:
        (ds,) = load_datasets([str(f)])
        assert_physical(fit_map([ds]).map, f.name)


def test_default_map_is_physical_on_the_xnova_pair_that_crossed(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Before: 1/B coefficient -776.6, c = +33.7 %: predict 0.05 N gave 5.0 % at 22.6 V and
    1.6 % at 20.2 V. Now more voltage never asks for more throttle, and fit says why."""
    sr = shared_data / "xnova-thrust-stand" / "single_rotor"
    m = tmp_path / "x.json"
    main(["fit", str(sr / "xNova-SR-steps.csv"), str(sr / "xNova-SR-steps-up.csv"), "-o", str(m)])
    text = capsys.readouterr().out
    # with the steps file read from its load cell's zero the free fit's k0 is -167.7 (it was
    # -776.6 before): still negative, so the bounded fit is kept and fit says why
    assert "negative no-load term" in text and "k0 = 0) kept" in text
    assert "rest plateau read 0.0614 N, subtracted" in text
    assert "voltage scaling: 1/B from motor physics" in text
    doc = json.loads(m.read_text())
    assert doc["identification"]["voltage_scaling"].startswith("1/B from motor physics")
    tmap = ThrustMap.load(m)
    assert_physical(tmap, "xNova SR steps + steps-up")
    answers = []
    for b in ("22.6", "20.2"):
        main(["predict", str(m), "--thrust-n", "0.05", "--voltage-v", b, "--json"])
        answers.append(json.loads(capsys.readouterr().out)["throttle_pct"])
    assert answers[0] < answers[1]


def test_bounded_fit_holds_the_offset_band_and_says_so() -> None:
    """Data whose free fit wants an ESC offset of -60 %: the map keeps c inside its band."""
    rng = np.random.default_rng(3)
    t = np.tile(np.linspace(0.3, 6.0, 20), 3)
    b = np.repeat([21.0, 22.5, 24.0], 20) + rng.normal(0, 0.05, 60)
    th = -60 + (2000 * np.sqrt(t) + 30 * t) / b
    coef, ident = MODELS["motor"].identify(t, b, th, "l2")
    assert ident is not None and ident.limited_by == "physical sense"
    assert "throttle offset c = -6" in ident.reason
    assert OFFSET_RANGE_PCT[0] <= coef[0] <= OFFSET_RANGE_PCT[1]
    assert min(coef[1:]) >= 0
    # l1 holds the same bounds
    coef1, _ = MODELS["motor"].identify(t, b, th, "l1")
    assert OFFSET_RANGE_PCT[0] - 1e-6 <= coef1[0] and min(coef1[1:]) >= -1e-9


def test_held_out_folds_use_the_same_bounds() -> None:
    """compare's fast held-out path solves in a conditioned basis: the bounds must hold there."""
    from thrustmap.core.units import SCALES
    from thrustmap.fitting.dataset import Dataset
    from thrustmap.fitting.fit.coefficients import fit_coefficients
    from thrustmap.fitting.fit.validation import compare
    from thrustmap.fitting.selection.options import Selection

    rng = np.random.default_rng(5)
    sets = []
    for k, volts in enumerate((21.0, 22.5, 24.0)):
        t = np.linspace(0.3, 6.0, 40)
        b = volts + rng.normal(0, 0.05, 40)
        th = -60 + (2000 * np.sqrt(t) + 30 * t) / b + rng.normal(0, 0.3, 40)
        sets.append(
            Dataset(
                path=f"f{k}.csv",
                format="synthetic",
                throttle_scale=SCALES["pwm"],
                throttle_native=SCALES["pwm"].from_pct(th),
                thrust_n=t,
                voltage_v=b,
                line=np.arange(40, dtype=np.int64) + 2,
            )
        )
    sel = Selection(all_samples=True)
    (fast,) = compare(sets, ["motor"], "by-file", selection=sel)
    # the same folds through the slow path (fit_coefficients) give the same held-out error
    errs = []
    for i in range(3):
        tr = [s for j, s in enumerate(sets) if j != i]
        t = np.concatenate([s.thrust_n for s in tr])
        b = np.concatenate([s.voltage_v for s in tr])
        th = np.concatenate([s.throttle_scale.to_pct(s.throttle_native) for s in tr])
        coef = fit_coefficients(MODELS["motor"], t, b, th, "l2")
        assert OFFSET_RANGE_PCT[0] <= coef[0]
        te = sets[i]
        pred = MODELS["motor"].evaluate(coef, te.thrust_n, te.voltage_v)
        errs.append(np.abs(pred - te.throttle_scale.to_pct(te.throttle_native)))
    assert fast.all.mean_pct == pytest.approx(float(np.mean(np.concatenate(errs))), rel=1e-6)


# -- the voltage scaling from the stand's rpm and current ---------------------------------------


def motor_file(voltage_v: float, name: str, *, i0_a: float = 3.0, r_ohm: float = 0.15):
    """A motor whose no-load drop R·I0 is large (a 1/B term k0 = 0 cannot hold it), logged
    with rpm and current as most stands do: 11 averaged steps."""
    from thrustmap.core.units import SCALES
    from thrustmap.fitting.dataset import Dataset

    kv_rad = 2400.0 * 2 * np.pi / 60.0
    kt = 2.5e-6
    thrust = np.linspace(0.2, 4.0, 11)
    omega = np.sqrt(thrust / kt)
    current = i0_a + kt * 0.012 * omega**2 * kv_rad
    volts = voltage_v - 0.01 * current
    th = -5.0 + 100.0 * (omega / kv_rad + r_ohm * current) / volts
    rng = np.random.default_rng(int(voltage_v * 10))  # sensor noise: 0.3 % throttle, 1 % rpm
    th = th + rng.normal(0, 0.3, len(th))
    omega = omega * (1 + rng.normal(0, 0.01, len(th)))
    current = current * (1 + rng.normal(0, 0.01, len(th)))
    return Dataset(
        path=name,
        format="synthetic",
        throttle_scale=SCALES["pwm"],
        throttle_native=SCALES["pwm"].from_pct(th),
        thrust_n=thrust,
        voltage_v=volts,
        line=np.arange(11, dtype=np.int64) + 2,
        current_a=current,
        rpm=omega * 60 / (2 * np.pi) * 7,  # electrical rpm (7 pole pairs): any scale will do
    )


def test_backemf_scaling_is_kept_where_held_out_error_confirms_it() -> None:
    from thrustmap.fitting.fit.validation import evaluate
    from thrustmap.fitting.models import SCALING_BACKEMF
    from thrustmap.fitting.selection.options import Selection

    sel = Selection(all_samples=True)
    train = [motor_file(7.4, "2s.csv"), motor_file(11.1, "3s.csv")]
    out = fit_map(train, selection=sel)
    ident = out.map.identification
    assert ident["form"] == "back-EMF" and ident["voltage_scaling"] == SCALING_BACKEMF
    assert ident["evidence"]["held_out_backemf_pct"] < ident["evidence"]["held_out_thrust_form_pct"]
    assert out.map.coefficients[1] > 0  # k0 = R·I0 measured, not assumed 0
    assert_physical(out.map, "back-EMF map")
    # and it carries to a voltage it never saw better than the thrust-only identification
    from dataclasses import replace

    test = motor_file(14.8, "4s.csv")
    (row,) = evaluate(out.map, [test], sel)
    plain = fit_map([replace(d, rpm=None) for d in train], selection=sel)  # no rpm logged
    assert "back-EMF" not in plain.map.identification["voltage_scaling"]
    (row_plain,) = evaluate(plain.map, [test], sel)
    assert row.all.mean_pct < 0.5 * row_plain.all.mean_pct, (row.all, row_plain.all)


def test_backemf_scaling_not_kept_on_a_real_pair_and_said(shared_data: Path) -> None:
    folder = shared_data / "third-party-stands" / "strawson-5inch"
    ds = load_datasets([str(folder / "b2_7.csv"), str(folder / "b2_11.csv")])
    ident = fit_map(ds).map.identification
    assert ident["form"] != "back-EMF"
    assert (
        "back-EMF scaling from the logged rpm and current tried and not kept"
        in (ident["voltage_scaling"])
    )
    # one voltage: nothing could confirm it, and the map says so
    (one,) = load_datasets([str(folder / "b2_7.csv")])
    assert "not tried" in fit_map([one]).map.identification["voltage_scaling"]
