"""The smaller untruths of issue 35, one test each: what a newcomer read that was not so."""

from __future__ import annotations

import io
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest
from click.testing import CliRunner

from thrustmap.cli import main

ROOT = Path(__file__).resolve().parent.parent
FIXTURES = ROOT / "fixtures"
RUN_CSV = FIXTURES / "sweeps" / "msp_run.csv"


def invoke(*args: str) -> tuple[int, str, str]:
    """``thrustmap ARGS`` through main(), as the console script runs it: exit code, stdout,
    stderr."""
    with CliRunner().isolation() as (out, err, _):
        try:
            main(list(args))
            code = 0
        except SystemExit as exc:
            code = int(exc.code or 0)
        return code, out.getvalue().decode(), err.getvalue().decode()


@pytest.fixture(scope="module")
def small_map(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A map fitted on the shipped simulated sweep (one file, 6S)."""
    out = tmp_path_factory.mktemp("map") / "map.json"
    code, _, err = invoke("fit", str(RUN_CSV), "-o", str(out))
    assert code == 0, err
    return out


# -- the PX4 export -------------------------------------------------------------------------------


def test_cells_are_read_from_the_pack_voltage() -> None:
    from thrustmap.core.physical import cells_from_voltage

    assert cells_from_voltage(20.4, 25.2) == 6  # the paper's xNova pack
    assert cells_from_voltage(22.62, 22.62) == 6
    assert cells_from_voltage(3.1, 3.9) == 1  # a Crazyflie cell
    assert cells_from_voltage(11.1, 12.6) == 3
    assert cells_from_voltage(1.0, 9.0) is None  # no count holds 1..9 V at 3-4.35 V a cell


def test_px4_export_gives_bat1_v_charged_per_cell(small_map: Path) -> None:
    code, out, err = invoke("export", str(small_map), "--to", "px4")
    assert code == 0, err
    line = next(ln for ln in out.splitlines() if "BAT1_V_CHARGED" in ln)
    assert "recommended value below" not in line
    m = re.search(r"BAT1_V_CHARGED = ([\d.]+) V \(per cell: ([\d.]+) V on (\d+) cells", line)
    assert m, line
    per_cell, pack, cells = float(m[1]), float(m[2]), int(m[3])
    assert cells == 6 and 3.0 <= per_cell <= 4.35
    assert per_cell * cells == pytest.approx(pack, abs=0.01)


# -- words a newcomer should not see --------------------------------------------------------------


def test_a_px4_sweep_does_not_warn_with_an_internal_name(tmp_path: Path) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "thrustmap", "sweep", "steps", "--stand", "sim://tyto-1585",
         "--throttle", "sim://px4", "--to", "20", "--step", "10", "--dwell", "1", "--fast",
         "--yes", "-q", "-o", str(tmp_path / "run.csv")],
        capture_output=True, text=True, timeout=180, cwd=tmp_path,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "verify_stopped" not in proc.stderr and "not acknowledged" not in proc.stderr
    assert "stop verified" in proc.stdout


def test_px4_unknown_current_is_not_minus_one_amp() -> None:
    from thrustmap.protocols.mavlink.codec import decode_battery_status, decode_sys_status

    msg = SimpleNamespace(
        id=0, voltages=[16200] + [65535] * 9, voltages_ext=[], current_battery=-100,
        temperature=32767, current_consumed=-1, energy_consumed=-1, battery_remaining=-1,
    )  # fmt: skip
    assert decode_battery_status(msg).current_a is None
    sys_msg = SimpleNamespace(voltage_battery=16200, current_battery=-100, battery_remaining=50)
    assert decode_sys_status(sys_msg).current_a is None
    sys_msg.current_battery = 250
    assert decode_sys_status(sys_msg).current_a == pytest.approx(2.5)


def test_replayed_real_recordings_say_what_is_unknown(shared_data: Path) -> None:
    transcripts = shared_data / "firmware-transcripts"
    code, out, err = invoke("probe", f"replay://{transcripts / 'ardupilot' / 'probe.jsonl'}")
    assert code == 0, err
    assert "None None" not in out + err and "frame: unknown" in out
    code, out, err = invoke("probe", f"replay://{transcripts / 'px4' / 'probe.jsonl'}")
    assert code == 0, err
    assert "-1.00 A" not in out and "current not measured" in out
    # the recording's driver stopped the motors before re-enabling arming; a probe that never ran
    # a motor sends no stop, and the replay must not call that a divergence
    code, out, err = invoke("probe", f"replay://{transcripts / 'betaflight' / 'probe.jsonl'}")
    assert code == 0 and "could not re-enable arming" not in err, err


# -- flightlog inspect ----------------------------------------------------------------------------


def test_flightlog_inspect_gives_one_time_base() -> None:
    code, out, err = invoke("flightlog", "inspect", str(FIXTURES / "flightlogs" / "sim_hover.ulg"))
    assert code == 0, err
    m = re.search(r"duration ([\d.]+) s \(log time ([\d.]+) \.\. ([\d.]+) s", out)
    assert m, out
    start, end = float(m[2]), float(m[3])
    assert float(m[1]) == pytest.approx(end - start, abs=0.11)
    windows = re.findall(r"^\s+([\d.]+) \.\. ([\d.]+) s \(", out, re.M)
    assert windows and all(start - 0.1 <= float(a) <= float(b) <= end + 0.1 for a, b in windows)


def test_flightlog_inspect_of_a_folder_says_what_to_do(tmp_path: Path) -> None:
    (tmp_path / "a.txt").write_text("x")
    code, _, err = invoke("flightlog", "inspect", str(tmp_path))
    assert code == 2
    assert "first bytes b''" not in err and "is a folder" in err and "fleet extract" in err


def test_an_empty_df_is_summarised_once(tmp_path: Path) -> None:
    log = FIXTURES / "flightlogs" / "sim_hover.ulg"
    code, out, err = invoke(
        "flightlog", "extract", str(log), "--mass-kg", "1.5", "--settle-s", "100",
        "-o", str(tmp_path / "df.csv"),
    )  # fmt: skip
    assert code == 0, err
    assert "no steady flight to extract" in err and "kept 0.0 of" in err
    assert (out + err).count("within 100 s of takeoff or landing") == 1, out + err


# -- the demo re-runs in place --------------------------------------------------------------------


def _fake_demo_output(out_dir: Path) -> list[Path]:
    from thrustmap.demo import recording_paths

    paths = recording_paths(out_dir)
    for p in paths:
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(f"recorded {p.name}\n")
    return paths


def test_the_demo_replaces_its_own_recordings(tmp_path: Path) -> None:
    from thrustmap.demo import _remember, clear_previous_run, manifest_path

    paths = _fake_demo_output(tmp_path)
    _remember(tmp_path, paths)
    assert manifest_path(tmp_path, "sr").exists() and manifest_path(tmp_path, "mr").exists()
    # (kept out of the data folders: `thrustmap fit thrustmap-demo/sr/*` finds logs only)
    assert not list(tmp_path.glob("*/thrustmap-demo.json"))
    assert clear_previous_run(tmp_path) == len(paths)
    assert not any(p.exists() for p in paths)


def test_the_demo_never_replaces_a_users_recording(tmp_path: Path) -> None:
    from thrustmap.core.errors import ConfigError
    from thrustmap.demo import _remember, clear_previous_run

    paths = _fake_demo_output(tmp_path)
    _remember(tmp_path, paths)
    paths[3].write_text("the user's own sweep\n")  # same name, other content
    with pytest.raises(ConfigError, match="did not write") as info:
        clear_previous_run(tmp_path)
    assert "-o" in str(info.value)
    assert all(p.exists() for p in paths)  # refused before anything was removed
    for p in paths:  # no manifest at all: nothing is the demo's
        p.write_text("x\n")
    for manifest in tmp_path.glob(".thrustmap-demo/*/thrustmap-demo.json"):
        manifest.unlink()
    with pytest.raises(ConfigError):
        clear_previous_run(tmp_path)


# -- the live panel -------------------------------------------------------------------------------


def test_the_live_panel_shows_no_eta_before_the_plan() -> None:
    from thrustmap.cli.live import LiveView

    view = LiveView("sweep steps", live=False, stream=io.StringIO(), phase="tare")
    line = view.plain_line()
    assert "ETA" not in line and "0/0 s" not in line, line
    panel = view.render(80)
    text = "\n".join(str(t) for t in panel.renderables)
    assert "ETA" not in text and " 0 %" not in text and "not started" in text, text


def test_a_raw_throttle_has_its_unit() -> None:
    from thrustmap.cli.live import _native

    assert _native(647.7, "") == "647.7 raw"
    assert _native(0.1, "1") == "0.100 of full scale"
    assert _native(1100, "us") == "1100 us"


def test_counts_agree_with_their_nouns(small_map: Path) -> None:
    from thrustmap.cli.textwidth import plural

    assert (plural(1, "log"), plural(2, "log"), plural(0, "plateau")) == (
        "1 log", "2 logs", "0 plateaus",
    )  # fmt: skip
    code, out, _ = invoke("fit", str(RUN_CSV), "-o", str(small_map.with_name("again.json")))
    assert code == 0 and not re.search(r"\b1 (plateaus|points|samples)\b", out)


# -- one term: supported region -------------------------------------------------------------------


def test_compare_speaks_of_the_supported_region(small_map: Path) -> None:
    code, out, err = invoke("compare", str(RUN_CSV), "--models", "motor,poly1", "--validate",
                            "in-sample", "--json")  # fmt: skip
    assert code == 0, err
    row = json.loads(out)["rows"][0]
    assert row["inside_supported_region"] == row["inside_box"]  # the old name still readable
    assert row["outside_supported_region"] == row["outside_box"]
    code, out, err = invoke("compare", str(RUN_CSV), "--models", "motor", "--validate", "in-sample")
    assert code == 0 and "supported region" in out and "box" not in out, out


# -- the report -----------------------------------------------------------------------------------


def test_the_coverage_legend_covers_no_data(small_map: Path) -> None:
    from thrustmap.report import figures
    from thrustmap.report.data import build

    rd = build(small_map, [str(RUN_CSV)], with_exports=False, with_validation=False)
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    fig = figures.coverage(rd)
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    assert all(ax.get_legend() is None for ax in fig.axes)
    assert fig.legends, "the legend is the figure's, below the panels"
    legend = fig.legends[0].get_window_extent(renderer)
    for ax in fig.axes[:2]:
        assert not legend.overlaps(ax.get_window_extent(renderer))


def test_error_bars_stay_in_their_bin() -> None:
    from thrustmap.report import figures

    bins = [
        {"voltage_v": [22.00 + 0.03 * i, 22.03 + 0.03 * i], "samples": 30,
         "e_Th_before_pct": {"mean": 2.0, "std": 0.3}, "e_Th_after_pct": {"mean": 1.0, "std": 0.2},
         "e_T_before_pct": {"mean": 3.0, "std": 0.3}, "e_T_after_pct": {"mean": 1.5, "std": 0.2}}
        for i in range(5)
    ]  # fmt: skip
    rd = SimpleNamespace(gamma=SimpleNamespace(metrics={"by_voltage": bins}))
    fig = figures.errors_by_voltage(rd)  # type: ignore[arg-type]
    for ax in fig.axes:
        for line in ax.get_lines():
            for x in line.get_xdata():
                assert any(b["voltage_v"][0] <= x <= b["voltage_v"][1] for b in bins), x


def test_a_coefficient_held_at_zero_prints_as_zero(small_map: Path, tmp_path: Path) -> None:
    from thrustmap.report.data import build
    from thrustmap.report.html import render_html

    data = json.loads(small_map.read_text(encoding="utf-8"))
    coefs = data["coefficients"]
    k = next(i for i, c in enumerate(coefs) if c != 0)
    coefs[(k + 1) % len(coefs)] = 3.61848e-14
    edited = tmp_path / "edited.json"
    edited.write_text(json.dumps(data), encoding="utf-8")
    html = render_html(build(edited, [str(RUN_CSV)], with_exports=False, with_validation=False))
    assert "3.61848e-14" not in html


def test_the_nav_bar_is_one_line(small_map: Path, tmp_path: Path) -> None:
    """At 1280 px (the screenshot test's width) the nav bar holds one line of links: short
    labels, and it never wraps (it scrolls sideways if a narrower window must)."""
    from thrustmap.report.data import build
    from thrustmap.report.html import CSS, render_html

    html = render_html(build(small_map, [str(RUN_CSV)], with_exports=False))
    nav = re.search(r"<nav>(.*?)</nav>", html, re.S)
    assert nav
    labels = re.findall(r">([^<]+)</a>", nav[1])
    # 14 px system font: about 7.5 px a character, 14 px between links, 56 px padding
    assert sum(len(t) * 7.5 + 14 for t in labels) + 56 < 1280 * 0.8, labels
    assert "white-space:nowrap" in CSS.split("nav{", 1)[1].split("}", 1)[0]


def test_the_nav_bar_does_not_wrap_in_chromium_at_1280px(small_map: Path, tmp_path: Path) -> None:
    import matplotlib.image as mpimg
    import numpy as np

    browser = next(
        (shutil.which(n) for n in (os.environ.get("THRUSTMAP_CHROMIUM", ""), "chromium",
                                   "chromium-browser") if n and shutil.which(n)),
        None,
    )  # fmt: skip
    if browser is None:
        pytest.skip("no headless Chromium installed (Debian: apt-get install chromium)")
    from thrustmap.report.data import build
    from thrustmap.report.html import write_report

    html = tmp_path / "report.html"
    write_report(build(small_map, [str(RUN_CSV)]), str(html))
    shot = tmp_path / "shot.png"
    subprocess.run(
        [browser, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
         "--no-first-run", f"--screenshot={shot}", "--window-size=1280,900", html.as_uri()],
        capture_output=True, text=True, timeout=120, check=True,
    )  # fmt: skip
    img = mpimg.imread(shot)[..., :3]
    nav_colour = np.array([0xEE, 0xF1, 0xF6]) / 255.0
    column = img[:300, 4]  # left padding: nav background, no text
    rows = np.flatnonzero(np.all(np.abs(column - nav_colour) < 0.02, axis=1))
    assert rows.size, "no nav bar found"
    height = int(rows[-1] - rows[0] + 1)
    assert rows.size == height, "the nav band is one block"
    assert 20 <= height <= 45, f"nav bar {height} px high: wrapped onto a second line"
