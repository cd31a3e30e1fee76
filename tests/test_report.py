"""`thrustmap report` and `thrustmap plot`: content, numbers equal to the CLI's, a real browser.

The acceptance maps: `thrustmap demo`'s SR map with a γ block from a simulated flight (through
`flightlog extract` and `gamma fit`), and the xNova SR stand files (skipped when ../shared is
absent). Browser tests run Debian's headless Chromium and skip with a reason when it is absent.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from support import simulate_flight as sim
from support.shared import ABSENT_REASON as SHARED_ABSENT
from support.shared import shared_data_dir
from support.terminal import DemoRun

from thrustmap.cli import COMMANDS, main
from thrustmap.fitting.mapfile import ThrustMap
from thrustmap.report.html import SECTIONS

XNOVA_SR = ("xNova-SR-ramp.csv", "xNova-SR-steps-up.csv", "xNova-SR-steps.csv", "xNova-TM-SR.csv")
TABLE_MODELS = "poly2,poly2-trunc,poly3,poly3-trunc,motor"


def run_cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = 0
    try:
        main(args)
    except SystemExit as exc:
        code = int(exc.code or 0)
    out = capsys.readouterr()
    return code, out.out, out.err


def chromium() -> str:
    for name in (os.environ.get("THRUSTMAP_CHROMIUM", ""), "chromium", "chromium-browser"):
        if name and shutil.which(name):
            return str(shutil.which(name))
    pytest.skip("no headless Chromium installed (Debian: apt-get install chromium)")


def browser(html: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
         "--no-first-run", *args, html.resolve().as_uri()],
        capture_output=True, text=True, timeout=120, check=True,
    )  # fmt: skip


class Cells(HTMLParser):
    """data-key -> (data-value, data-std) of every table cell; ids of sections; h2 texts."""

    def __init__(self) -> None:
        super().__init__()
        self.cells: dict[str, tuple[str, str | None]] = {}
        self.ids: set[str] = set()
        self.h2: list[str] = []
        self.canvas_style = ""
        self._in_h2 = False

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        if a.get("id"):
            self.ids.add(str(a["id"]))
        if tag == "td" and a.get("data-key"):
            self.cells[str(a["data-key"])] = (str(a["data-value"]), a.get("data-std"))
        if tag == "canvas":
            self.canvas_style = a.get("style") or ""
        self._in_h2 = tag == "h2"

    def handle_data(self, data: str) -> None:
        if self._in_h2:
            self.h2.append(data)
            self._in_h2 = False


def parse(text: str) -> Cells:
    p = Cells()
    p.feed(text)
    return p


# -- fixtures -------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def demo(demo_run: DemoRun) -> dict[str, Any]:
    """`thrustmap demo` (the session's one run), then a simulated flight on its SR map,
    `flightlog extract`, `gamma fit`."""
    assert demo_run.code == 0, demo_run.output
    out = demo_run.folder / "thrustmap-demo"
    # a long path goes on its own line after "Report:" at 80 columns (wrapped between words)
    reports = re.findall(r"^Report:\s+(\S+)", demo_run.output, re.M)
    sr_map = out / "sr-map.json"
    tmap = ThrustMap.load(sr_map)
    flight = sim.simulate_hover(
        sim.HoverSim(seed=1, duration_s=90.0, rate_hz=25.0, voltage_start_v=24.9,
                     voltage_end_v=23.3),
        stand_map=tmap,
    )  # fmt: skip
    sim.write_dataflash(flight, out / "hover.bin")
    cli = [sys.executable, "-m", "thrustmap"]
    subprocess.run(
        [*cli, "flightlog", "extract", str(out / "hover.bin"), "--mass-kg", "1.0", "--map",
         str(sr_map), "-o", str(out / "hover-df.csv")],
        capture_output=True, text=True, timeout=300, check=True,
    )  # fmt: skip
    fit = subprocess.run(
        [*cli, "gamma", "fit", str(out / "hover-df.csv"), "--map", str(sr_map), "-o",
         str(out / "sr-gamma-map.json"), "--json"],
        capture_output=True, text=True, timeout=300, check=True,
    )  # fmt: skip
    html = out / "sr-gamma-report.html"
    subprocess.run(
        [*cli, "report", str(out / "sr-gamma-map.json"), "-o", str(html)],
        capture_output=True, text=True, timeout=300, check=True,
    )  # fmt: skip
    return {
        "dir": out,
        "stdout": demo_run.output,
        "reports": reports,
        "map": out / "sr-gamma-map.json",
        "logs": [str(demo_run.folder / s["path"]) for s in tmap.sources],
        "gamma": json.loads(fit.stdout),
        "html": html,
    }


@pytest.fixture(scope="module")
def xnova(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    shared = shared_data_dir()
    if shared is None:
        pytest.skip(SHARED_ABSENT)
    root = shared / "xnova-thrust-stand" / "single_rotor"
    files = [root / f for f in XNOVA_SR]
    assert all(f.is_file() for f in files), f"xNova SR files missing in {root}"
    out = tmp_path_factory.mktemp("xnova")
    cli = [sys.executable, "-m", "thrustmap"]
    subprocess.run([*cli, "fit", *map(str, files), "-o", str(out / "map.json")],
                   capture_output=True, text=True, timeout=300, check=True)  # fmt: skip
    html = out / "report.html"
    subprocess.run([*cli, "report", str(out / "map.json"), "-o", str(html)],
                   capture_output=True, text=True, timeout=300, check=True)  # fmt: skip
    return {"map": out / "map.json", "logs": [str(f) for f in files], "html": html}


# -- content and self-containment -----------------------------------------------------------------


def test_demo_writes_a_report_per_map_and_prints_its_path(demo: dict[str, Any]) -> None:
    assert [Path(p).name for p in demo["reports"]] == ["sr-map-report.html", "mr-map-report.html"]
    for p in demo["reports"]:
        text = Path(p).read_text(encoding="utf-8")
        assert "<h2>Validation of every model</h2>" in text


def self_contained(text: str) -> list[str]:
    """Every reference that would need the network (or another file)."""
    bad = re.findall(r"""(?:src|href)\s*=\s*["']?\s*(?:https?:)?//[^"'\s>]+""", text, re.I)
    bad += re.findall(r"@import|url\(\s*['\"]?(?:https?:)?//", text, re.I)
    bad += re.findall(r"<link\b[^>]*>", text, re.I)
    bad += re.findall(r"<script\b[^>]*\bsrc\s*=", text, re.I)
    return bad


@pytest.mark.parametrize("which", ["demo", "xnova"])
def test_report_is_self_contained_and_small(which: str, request: pytest.FixtureRequest) -> None:
    html = request.getfixturevalue(which)["html"]
    text = html.read_text(encoding="utf-8")
    assert self_contained(text) == []
    assert html.stat().st_size < 3_000_000
    assert text.count('src="data:image/png;base64,') >= 5  # 7 with γ


def test_self_containment_check_catches_network_references() -> None:
    assert self_contained('<script src="https://cdn.plot.ly/x.js"></script>')
    assert self_contained('<link rel="stylesheet" href="style.css">')
    assert self_contained("<style>@import url(//fonts.googleapis.com/x)</style>")
    assert self_contained('<img src="data:image/png;base64,AAAA">') == []


def test_gamma_section_only_when_the_map_has_gamma(demo: dict[str, Any]) -> None:
    plain = Path(demo["reports"][0]).read_text(encoding="utf-8")
    assert "This map has no γ(B) flight correction" in plain
    assert 'id="fig-gamma"' not in plain
    corrected = demo["html"].read_text(encoding="utf-8")
    assert 'id="fig-gamma"' in corrected and 'id="fig-errors-by-voltage"' in corrected


# -- numbers equal the CLI's ----------------------------------------------------------------------


def compare_json(files: list[str], mode: str, capsys: pytest.CaptureFixture[str]) -> list[Any]:
    code, out, err = run_cli(
        ["compare", *files, "--models", TABLE_MODELS, "--validate", mode, "--json"], capsys
    )
    assert code == 0, err
    return list(json.loads(out)["rows"])


def check_validation(
    cells: dict[str, tuple[str, str | None]], files: list[str], capsys: Any
) -> int:
    checked = 0
    for mode in ("in-sample", "by-file", "kfold"):
        for row in compare_json(files, mode, capsys):
            k = f"{mode}:{row['model']}"
            value, std = cells[f"{k}:mean_pct"]
            assert float(value) == row["mean_pct"], k
            assert std is not None and float(std) == row["std_pct"], k
            assert int(cells[f"{k}:n"][0]) == row["n"]
            assert float(cells[f"{k}:p95_pct"][0]) == row["p95_pct"]
            assert float(cells[f"{k}:max_pct"][0]) == row["max_pct"]
            if mode != "in-sample":
                assert int(cells[f"{k}:outside_n"][0]) == row["outside_box"]["n"]
                assert int(cells[f"{k}:inside_n"][0]) == row["inside_box"]["n"]
            checked += 1
    return checked


def test_demo_report_numbers_equal_compare_and_gamma_fit_json(
    demo: dict[str, Any], capsys: pytest.CaptureFixture[str]
) -> None:
    cells = parse(demo["html"].read_text(encoding="utf-8")).cells
    assert check_validation(cells, demo["logs"], capsys) == 15
    metrics = demo["gamma"]["metrics"]
    for key in ("e_Th_before_pct", "e_Th_after_pct", "e_T_before_pct", "e_T_after_pct"):
        value, std = cells[key]
        assert float(value) == metrics[key]["mean"], key
        assert std is not None and float(std) == metrics[key]["std"], key
    for i, b in enumerate(metrics["by_voltage"]):
        assert int(cells[f"bin{i}:samples"][0]) == b["samples"]
        assert float(cells[f"bin{i}:e_Th_after_pct"][0]) == b["e_Th_after_pct"]["mean"]
    # γ reduced the error, as the simulated flight was built to show
    assert metrics["e_Th_after_pct"]["mean"] < metrics["e_Th_before_pct"]["mean"]


def test_xnova_report_numbers_equal_compare_json(
    xnova: dict[str, Any], capsys: pytest.CaptureFixture[str]
) -> None:
    cells = parse(xnova["html"].read_text(encoding="utf-8")).cells
    assert check_validation(cells, xnova["logs"], capsys) == 15


# -- a real browser -------------------------------------------------------------------------------


@pytest.mark.parametrize("which", ["demo", "xnova"])
def test_report_renders_in_headless_chromium(
    which: str, request: pytest.FixtureRequest, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The DOM Chromium built (after the script ran) has every section, the interactive view
    drawn, and the same numbers as the CLI; the screenshot is not blank."""
    import matplotlib.image as mpimg

    case = request.getfixturevalue(which)
    dom = parse(browser(case["html"], "--dump-dom", "--virtual-time-budget=3000").stdout)
    for key, title in SECTIONS:
        assert key in dom.ids, key
        assert title in dom.h2, title
    assert "display: block" in dom.canvas_style  # the inline script ran and drew the 3D view
    assert check_validation(dom.cells, case["logs"], capsys) == 15
    if which == "demo":
        assert float(dom.cells["e_Th_after_pct"][0]) == case["gamma"]["metrics"][
            "e_Th_after_pct"]["mean"]  # fmt: skip
    shot = tmp_path / "shot.png"
    browser(case["html"], f"--screenshot={shot}", "--window-size=1280,2400")
    img = mpimg.imread(shot)[..., :3]
    assert img.shape[0] >= 2000 and img.shape[1] >= 1200
    assert float(np.std(img)) > 0.05  # not blank: text, tables and figures
    assert float(np.mean(img < 0.5)) > 0.01  # dark ink present
    # the header band (dark) and the white page are both there
    assert float(np.mean(img[:40])) < 0.4 and float(np.mean(img[-200:])) > 0.5


# -- finding the data -----------------------------------------------------------------------------


def test_report_names_moved_sources_in_one_line(
    demo: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    moved = tmp_path / "elsewhere" / "map.json"
    moved.parent.mkdir()
    data = json.loads(demo["map"].read_text(encoding="utf-8"))
    for s in data["sources"]:
        s["path"] = "/nonexistent/" + Path(s["path"]).name
    moved.write_text(json.dumps(data), encoding="utf-8")
    code, out, err = run_cli(["report", str(moved), "-o", str(tmp_path / "r.html")], capsys)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "moved?" in lines[0] and "xnova-SR-steps.csv" in lines[0]
    assert not (tmp_path / "r.html").exists()
    # the same map with the logs given explicitly works
    code, out, err = run_cli(
        ["report", str(moved), *demo["logs"], "-o", str(tmp_path / "r.html")], capsys
    )
    assert code == 0, err
    assert "wrote" in out and (tmp_path / "r.html").is_file()


def test_report_finds_sources_moved_with_the_map(
    demo: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A folder moved as a whole: the logs are found next to the map by name."""
    data = json.loads(demo["map"].read_text(encoding="utf-8"))
    for s in data["sources"]:
        shutil.copy(s["path"], tmp_path / Path(s["path"]).name)
        s["path"] = "/old/place/" + Path(s["path"]).name
    data["correction"] = None
    (tmp_path / "map.json").write_text(json.dumps(data), encoding="utf-8")
    code, out, err = run_cli(["report", str(tmp_path / "map.json"), "-o", str(tmp_path / "r.html")],
                             capsys)  # fmt: skip
    assert code == 0, err
    text = (tmp_path / "r.html").read_text(encoding="utf-8")
    assert f"{tmp_path}/xnova-SR-steps.csv" in text


def test_report_refuses_to_overwrite_its_input(
    demo: dict[str, Any], capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = run_cli(["report", str(demo["map"]), "-o", str(demo["map"])], capsys)
    assert code == 2
    assert json.loads(demo["map"].read_text(encoding="utf-8"))["format"] == "thrustmap.map"


# -- plot -----------------------------------------------------------------------------------------


MAGIC = {"png": b"\x89PNG", "svg": b"<?xml", "pdf": b"%PDF"}


@pytest.mark.parametrize(
    ("figure", "fmt"),
    [("surface", "png"), ("slices", "svg"), ("residuals", "pdf"), ("coverage", "png"),
     ("sweep", "png"), ("gamma", "svg"), ("errors-by-voltage", "pdf")],
)  # fmt: skip
def test_plot_writes_each_figure(
    demo: dict[str, Any], figure: str, fmt: str, tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    out = tmp_path / f"fig.{fmt}"
    code, stdout, err = run_cli(["plot", figure, str(demo["map"]), "-o", str(out)], capsys)
    assert code == 0, err
    assert out.read_bytes().startswith(MAGIC[fmt])
    assert out.stat().st_size > 5_000


def test_plot_refuses_bad_extension_and_missing_gamma(
    demo: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, _, err = run_cli(["plot", "surface", str(demo["map"]), "-o", str(tmp_path / "f.jpg")],
                           capsys)  # fmt: skip
    assert code == 2 and "expected a .png, .svg or .pdf" in err
    plain = demo["dir"] / "sr-map.json"
    code, _, err = run_cli(["plot", "gamma", str(plain), "-o", str(tmp_path / "g.png")], capsys)
    assert code == 2 and "no γ(B) correction" in err and len(err.strip().splitlines()) == 1


# -- help -----------------------------------------------------------------------------------------


def test_every_command_help_says_where_the_pictures_are(
    capsys: pytest.CaptureFixture[str],
) -> None:
    import click

    from thrustmap.cli import cli

    ctx = click.Context(cli)
    paths: list[list[str]] = []
    for name in COMMANDS:
        cmd = cli.get_command(ctx, name)
        assert cmd is not None, name
        paths.append([name])
        if isinstance(cmd, click.Group):
            paths += [[name, sub] for sub in cmd.commands]
    from thrustmap.cli.help_pictures import NONE

    for path in paths:
        code, out, _ = run_cli([*path, "--help"], capsys)
        assert code == 0
        assert ("Pictures:" in out) == (path[0] not in NONE), path


def test_gamma_section_says_when_the_df_moved(
    demo: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The γ numbers come from the map; the γ_j points need the Df, and the report says so."""
    data = json.loads(demo["map"].read_text(encoding="utf-8"))
    data["correction"]["sources"] = [{"path": "/gone/hover-df.csv", "sha256": "0" * 64}]
    (tmp_path / "map.json").write_text(json.dumps(data), encoding="utf-8")
    code, _, err = run_cli(
        ["report", str(tmp_path / "map.json"), *demo["logs"], "-o", str(tmp_path / "r.html")],
        capsys,
    )
    assert code == 0, err
    text = (tmp_path / "r.html").read_text(encoding="utf-8")
    assert "Df &#x27;/gone/hover-df.csv&#x27; not found" in text
    cells = parse(text).cells
    assert float(cells["e_T_after_pct"][0]) == demo["gamma"]["metrics"]["e_T_after_pct"]["mean"]


# -- layout at a laptop's width (issue 24) ----------------------------------------------------------

_MEASURE = """<script>window.addEventListener('load',function(){var bad=[];
document.querySelectorAll('.tw, table').forEach(function(e,i){
if(e.scrollWidth>e.clientWidth+1)bad.push(i+':'+e.scrollWidth+'>'+e.clientWidth)});
if(document.documentElement.scrollWidth>window.innerWidth+1)bad.push('page');
document.body.setAttribute('data-overflow',bad.join(' ')||'none')});</script>"""


@pytest.mark.parametrize("which", ["demo", "xnova"])
def test_report_tables_fit_1280_px_without_a_scrollbar(
    which: str, request: pytest.FixtureRequest, tmp_path: Path
) -> None:
    case = request.getfixturevalue(which)
    page = tmp_path / "measured.html"
    page.write_text(
        case["html"].read_text(encoding="utf-8").replace("</body>", _MEASURE + "</body>"),
        encoding="utf-8",
    )
    dom = browser(page, "--dump-dom", "--window-size=1280,2400", "--virtual-time-budget=3000")
    found = re.search(r'data-overflow="([^"]*)"', dom.stdout)
    assert found is not None, "the measuring script did not run"
    assert found.group(1) == "none"


def test_titles_name_the_map_file_when_no_strategy_was_recorded(
    demo: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    raw = json.loads(Path(demo["map"]).read_text(encoding="utf-8"))
    raw["strategy"] = "unknown"
    nameless = tmp_path / "bench-2026-11.json"
    nameless.write_text(json.dumps(raw), encoding="utf-8")
    for s in raw["sources"]:  # the report finds the logs beside the map or where they were
        p = Path(str(s["path"]))
        if not p.is_absolute():
            s["path"] = str(Path(demo["map"]).parent / p)
    nameless.write_text(json.dumps(raw), encoding="utf-8")
    html = tmp_path / "r.html"
    code, _, err = run_cli(["report", str(nameless), "-o", str(html)], capsys)
    assert code == 0, err
    text = html.read_text(encoding="utf-8")
    assert "unknown + γ(B)" not in text and "unknown map" not in text
    assert "bench-2026-11.json + γ(B)" in text
