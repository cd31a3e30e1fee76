"""The top of a file's thrust curve (fitting/selection/top.py): an ESC that saturates below the
command's top, or cuts back, gives points that are no map points; a supply that sags is no top.
And an RCbenchmark log in DShot mode ('ESC signal' without a unit) loads."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from support.public_data import PublicFiles

from thrustmap.cli import cli, main
from thrustmap.fitting.loaders.load import load_datasets
from thrustmap.fitting.selection.options import Selection
from thrustmap.fitting.selection.points import select
from thrustmap.fitting.selection.top import past_the_top

HEADER = (
    "\ufeffTime (s),ESC signal (µs),Servo 1 (µs),Servo 2 (µs),Servo 3 (µs),Thrust (gf),"
    "Voltage (V),Current (A),Motor Electrical Speed (RPM),App message,"
)


def _curve(u_pct: np.ndarray, volts: np.ndarray, knee_pct: float = 200.0) -> np.ndarray:
    """Thrust (N) of a rotor whose ESC output stops at ``knee_pct``: T ∝ (u·B)²."""
    eff = np.minimum(u_pct, knee_pct) / 100.0
    return 0.9 * (eff * volts / 7.4) ** 2


def _write_steps(path: Path, esc_us: np.ndarray, thrust_n: np.ndarray, volts: np.ndarray) -> Path:
    rows = [HEADER]
    for i, (u, t, v) in enumerate(zip(esc_us, thrust_n, volts, strict=True)):
        rows.append(f"{0.2 + 3.5 * i:.1f},{u:.0f},,,,{t / 0.00980665:.3f},{v:.3f},1.0,20000,,")
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return path


def test_a_saturated_esc_is_found_and_its_plateau_left_out() -> None:
    u = np.arange(20.0, 100.1, 4.0)
    v = np.linspace(7.6, 7.2, len(u))
    cut = past_the_top(u, _curve(u, v, knee_pct=84.0), v)
    assert cut is not None and cut.kind == "saturation"
    assert cut.knee_throttle_pct == pytest.approx(84.0)
    assert cut.past.sum() == 4  # 88, 92, 96, 100 %
    assert cut.last_throttle_pct == pytest.approx(100.0)


def test_a_healthy_curve_with_noise_never_fires() -> None:
    rng = np.random.default_rng(7)
    for _ in range(300):
        u = np.arange(rng.uniform(5, 30), 100.1, rng.choice([1.0, 2.0, 4.0, 10.0]))
        v = np.full(len(u), rng.uniform(7, 25))
        t = _curve(u, v) * (1 + rng.normal(0, 0.01, len(u)))
        assert past_the_top(u, t, v) is None


def test_a_dense_noisy_ramp_with_a_dead_band_never_fires() -> None:
    rng = np.random.default_rng(11)
    for _ in range(100):
        u = np.sort(rng.uniform(0.0, 100.0, int(rng.integers(200, 2000))))
        v = np.full(len(u), rng.uniform(3.5, 25.0))
        t = np.where(u < 8.0, 0.0, _curve(u - 8.0, v)) + rng.normal(0, 0.03, len(u)) * _curve(
            np.full(len(u), 92.0), v
        )
        keep = t > 0
        assert past_the_top(u[keep], t[keep], v[keep]) is None


def test_one_high_reading_followed_by_a_rising_curve_is_no_top() -> None:
    # a load-cell glitch at 50 %: one step reads above full throttle, then the curve rises on
    u = np.arange(10.0, 100.1, 10.0)
    v = np.full(len(u), 11.1)
    t = _curve(u, v)
    t[u == 50.0] = 1.3 * t[-1]
    assert past_the_top(u, t, v) is None


def test_a_supply_that_sags_at_the_top_is_no_top() -> None:
    # Strawson's 3S runs: 10.8 V at 81 %, 9.4 V at 90 %, 8.3 V at 100 %, thrust 4.08 -> 3.70 N
    u = np.array([5, 14, 24, 34, 43, 52, 62, 72, 81, 90, 100.0])
    t = np.array([0.15, 0.36, 0.65, 0.98, 1.37, 1.86, 2.49, 3.23, 4.08, 3.94, 3.70])
    v = np.array([11.1, 11.1, 11.1, 11.0, 11.0, 11.0, 10.9, 10.9, 10.8, 9.4, 8.3])
    assert past_the_top(u, t, v) is None


def test_thrust_falling_at_a_steady_voltage_is_a_cut_back() -> None:
    u = np.arange(10.0, 100.1, 5.0)
    v = np.full(len(u), 3.4)
    t = _curve(u, v)
    t[u > 80] = t[u == 80][0] * np.linspace(0.95, 0.7, int((u > 80).sum()))
    cut = past_the_top(u, t, v)
    assert cut is not None and cut.kind == "cut-back"
    assert cut.knee_throttle_pct == pytest.approx(80.0)


def test_fit_leaves_the_plateau_out_and_exports_the_thrust_where_the_esc_saturated(
    tmp_path: Path,
) -> None:
    esc = np.arange(1200.0, 2001.0, 40.0)
    u = (esc - 1000.0) / 10.0
    v = np.linspace(7.59, 7.19, len(esc))
    log = _write_steps(tmp_path / "StepsTest_sat.csv", esc, _curve(u, v, knee_pct=84.0), v)
    runner = CliRunner()
    out = runner.invoke(cli, ["fit", str(log), "-o", str(tmp_path / "m.json")])
    assert out.exit_code == 0, out.output
    assert "thrust stops rising at 84.0 % throttle" in out.output
    assert "the ESC's output saturates" in out.output
    seen = runner.invoke(cli, ["inspect", str(log)])
    assert "top of the curve: thrust stops rising at 84.0 % throttle" in seen.output
    doc = json.loads((tmp_path / "m.json").read_text())
    assert doc["saturation"]["throttle_pct"] == pytest.approx(84.0)
    assert doc["validity"]["throttle_pct"][1] == pytest.approx(84.0)
    assert doc["saturation"]["files"] == ["StepsTest_sat.csv"]
    rep = runner.invoke(cli, ["report", str(tmp_path / "m.json"), "-o", str(tmp_path / "r.html")])
    assert rep.exit_code == 0, rep.output
    html = (tmp_path / "r.html").read_text(encoding="utf-8")
    assert "thrust stops rising at 84.0 % throttle" in html
    assert "saturated at 84 % (1840 µs) on the stand" in html

    def export(to: str, name: str, *extra: str) -> str:
        args = ["export", str(tmp_path / "m.json"), "--to", to, "-o", str(tmp_path / name)]
        res = runner.invoke(cli, [*args, *extra])
        assert res.exit_code == 0, res.output
        return (tmp_path / name).read_text(encoding="utf-8")

    # the output range ends where the ESC saturated (as its low end rises to the spin-up)
    px4 = export("px4", "p.params")
    assert "\tPWM_MAIN_MAX1\t1840\t" in px4
    assert "PWM maximum lowered from 2000 to 1840 us" in px4
    ap = export("ardupilot", "a.parm")
    assert "MOT_PWM_MAX,1840\n" in ap
    assert "MOT_PWM_MAX lowered from 2000 to 1840 us" in ap
    # a range given is kept; the values above the saturation are the thrust there, said so
    px4_kept = export("px4", "pk.params", "--range", "1240:2000")
    assert "\tPWM_MAIN_MAX1\t2000\t" in px4_kept
    assert "PWM maximum 2000 us as given, above 1840 us" in px4_kept
    line = next(x for x in px4_kept.splitlines() if "full-throttle thrust at" in x)
    assert "saturated at 84 % (1840 µs)" in line
    ap_lines = export("ardupilot", "ak.parm", "--range", "1000:2000").splitlines()
    for what in ("full-throttle thrust at", "thrust at MOT_SPIN_MAX (u = 1) at"):
        assert "saturated at 84 % (1840 µs)" in next(x for x in ap_lines if what in x)

    # predict answers the same: above 84 % the thrust at 84 %; more thrust is unreachable
    def ask(*args: str) -> dict:
        res = runner.invoke(cli, ["predict", str(tmp_path / "m.json"), *args, "--json"])
        assert res.exit_code in (0, 1), res.output
        return json.loads(res.stdout)

    at_knee = ask("--throttle-pct", "84", "--voltage-v", "7.3")["thrust_n"]
    above = ask("--throttle-pct", "97", "--voltage-v", "7.3")
    assert above["thrust_n"] == pytest.approx(at_knee)
    assert above["saturated_above_pct"] == pytest.approx(84.0)
    more = ask("--thrust-n", f"{at_knee * 1.03:.4f}", "--voltage-v", "7.3")
    assert more["reachable"] is False
    assert more["nearest_reachable_throttle_pct"] == pytest.approx(84.0)
    assert more["nearest_reachable_thrust_n"] == pytest.approx(at_knee)
    kept = runner.invoke(cli, ["fit", str(log), "--keep-past-top", "-o", str(tmp_path / "k.json")])
    assert kept.exit_code == 0, kept.output
    assert "saturation" not in json.loads((tmp_path / "k.json").read_text())
    assert json.loads((tmp_path / "k.json").read_text())["validity"]["throttle_pct"][1] == 100


def test_an_rcbenchmark_log_in_dshot_mode_loads_on_the_dshot_scale(tmp_path: Path) -> None:
    cmd = np.arange(100.0, 1801.0, 100.0)
    u = (cmd - 48.0) / 1999.0 * 100.0
    v = np.full(len(cmd), 16.5)
    path = _write_steps(tmp_path / "StepsTestV2_dshot.csv", cmd, _curve(u, v), v)
    path.write_text(path.read_text(encoding="utf-8").replace("ESC signal (µs)", "ESC signal"),
                    encoding="utf-8")  # fmt: skip
    (ds,) = load_datasets([str(path)])
    assert ds.throttle_scale.name == "dshot"
    assert ds.throttle_native[0] == pytest.approx(100.0)
    assert ds.throttle_pct[-1] == pytest.approx((1800 - 48) / 1999 * 100)
    assert "DShot" in ds.meta["assumed"]


def test_the_public_rcbenchmark_tops(public_data: PublicFiles) -> None:
    """diegosdantonio/thruststand_test: an ESC ending at 1840 µs driven to 2000 µs, and a 1S
    ramp whose ESC cuts back from 1825 µs (current 3.5 -> 1.6 A at the same voltage)."""
    found = {}
    for name in ("diegosdantonio/StepsTest_2020-06-16_212137",
                 "diegosdantonio/StepsTest20230615_2023-06-15_174003",
                 "diegosdantonio/StepsTest_2020-06-16_213055"):  # fmt: skip
        (ds,) = load_datasets([str(public_data(name))])
        found[name.rsplit("_", 1)[-1]] = select(ds, Selection()).report.get("past_top")
    assert found["212137"]["kind"] == "saturation"
    assert found["212137"]["knee_throttle_pct"] == pytest.approx(84.0)
    assert found["212137"]["points_dropped"] == 4
    assert found["174003"]["kind"] == "cut-back"
    assert 75.0 < found["174003"]["knee_throttle_pct"] < 82.5
    assert found["213055"] is None  # it stopped at 1832 µs, below the saturation


def test_a_hand_edited_saturation_is_refused_naming_the_field(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    esc = np.arange(1200.0, 2001.0, 40.0)
    u = (esc - 1000.0) / 10.0
    v = np.linspace(7.59, 7.19, len(esc))
    log = _write_steps(tmp_path / "StepsTest_sat.csv", esc, _curve(u, v, knee_pct=84.0), v)
    assert CliRunner().invoke(cli, ["fit", str(log), "-o", str(tmp_path / "m.json")]).exit_code == 0
    doc = json.loads((tmp_path / "m.json").read_text())
    for bad in ("abc", 140.0, None):
        doc["saturation"]["throttle_pct"] = bad
        (tmp_path / "bad.json").write_text(json.dumps(doc))
        capsys.readouterr()
        with pytest.raises(SystemExit) as exc:
            main(["predict", str(tmp_path / "bad.json"), "--thrust-n", "0.5", "--voltage-v", "7.3"])
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert "field 'saturation'" in err and "expected a number in 0..100" in err


def test_files_that_disagree_on_a_saturation_give_no_saturated_full_throttle(
    tmp_path: Path,
) -> None:
    """One run saturating at 84 %, another of the same motor rising to 100 % (its ESC end
    points recalibrated between them): the saturation is no property of the map."""
    esc = np.arange(1200.0, 2001.0, 40.0)
    u = (esc - 1000.0) / 10.0
    v = np.linspace(7.59, 7.19, len(esc))
    sat = _write_steps(tmp_path / "StepsTest_a.csv", esc, _curve(u, v, knee_pct=84.0), v)
    rising = _write_steps(tmp_path / "StepsTest_b.csv", esc, _curve(u, v), v)
    out = CliRunner().invoke(cli, ["fit", str(sat), str(rising), "-o", str(tmp_path / "m.json")])
    assert out.exit_code == 0, out.output
    assert "StepsTest_a.csv: thrust stops rising at 84.0 %" in out.output
    assert "a file saturated where another file's thrust still rose" in out.output
    assert "saturation" not in json.loads((tmp_path / "m.json").read_text())
