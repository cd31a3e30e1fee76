"""The public API (issue 41): ``import thrustmap`` lists it without importing it, and the docs'
Python tour (docs/api.md) runs as written and gives the answers the CLI gives."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
API_PAGE = ROOT / "docs" / "api.md"
NAMES = {
    "Prediction", "compare", "corrected_map", "export", "extract_df", "fit", "fit_gamma",
    "load_map", "load_stand_logs", "open_bench", "plans", "predict", "read_flight_log",
    "save_map", "Limits", "MapChooser", "RunResult", "ScriptBench", "run_script", "script_exit_code",
}  # fmt: skip


def _python(code: str, cwd: Path = ROOT) -> str:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=cwd, env=env, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout


def test_help_lists_the_api_and_importing_it_loads_nothing_heavy() -> None:
    out = _python(
        "import sys, pydoc, thrustmap\n"
        "print(sorted(m for m in sys.modules if m.startswith(('numpy', 'thrustmap.'))))\n"
        "print(pydoc.render_doc(thrustmap, renderer=pydoc.plaintext))\n"
    )
    loaded, text = out.split("\n", 1)
    assert loaded == "[]", loaded  # import thrustmap imports neither numpy nor any submodule
    functions = text.split("FUNCTIONS", 1)[1]
    for name in NAMES - {"Prediction", "plans", "Limits", "MapChooser", "RunResult", "ScriptBench"}:
        assert re.search(rf"^    {name}\(", functions, re.M), f"help(thrustmap) lacks {name}"
    assert "class Prediction" in text and "plans" in text


def test_every_api_name_has_a_docstring_and_a_typed_signature() -> None:
    import inspect

    import thrustmap

    assert set(thrustmap.__all__) == NAMES | {"__version__"}
    import thrustmap.api

    # the lazy map lists thrustmap.api's names again (importing api there would cost every CLI
    # start): the two lists agree
    assert {n for n, m in thrustmap.API.items() if m == "thrustmap.api"} == set(
        thrustmap.api.__all__
    )
    for name in sorted(NAMES - {"plans"}):
        obj = getattr(thrustmap, name)
        assert (obj.__doc__ or "").strip(), name
        if inspect.isfunction(obj):
            sig = inspect.signature(obj)
            assert sig.return_annotation is not inspect.Signature.empty, name
            for p in sig.parameters.values():
                assert p.annotation is not inspect.Parameter.empty, f"{name}({p.name})"
    assert callable(thrustmap.plans.stairs)


def _blocks() -> list[str]:
    text = API_PAGE.read_text(encoding="utf-8")
    return re.findall(r"^```python\n(.*?)^```", text, re.M | re.S)


def test_the_docs_python_tour_runs_and_agrees_with_the_cli(tmp_path: Path) -> None:
    """Every block of docs/api.md, in order, in one interpreter, from a checkout-like folder
    (the fixtures where the README's tour has them); then the CLI on the same files."""
    blocks = _blocks()
    assert len(blocks) >= 4
    (tmp_path / "fixtures").symlink_to(ROOT / "fixtures")
    out = _python("\n".join(blocks), cwd=tmp_path)
    assert "held-out points" in out and "γ(B) coefficients" in out
    for name in ("tour-0.csv", "tour-1.csv", "map.json", "corrected.json"):
        assert (tmp_path / name).is_file(), name
    # the sweeps recorded what they were asked: rows at every stair level, stop verified
    meta = json.loads((tmp_path / "tour-0.meta.json").read_text())
    assert meta["outcome"]["status"] == "completed" and meta["stop_verified"] is True

    # the same prediction from the CLI on the saved map
    from click.testing import CliRunner

    from thrustmap.cli import cli

    res = CliRunner().invoke(
        cli,
        ["predict", str(tmp_path / "map.json"), "--thrust-n", "4.2", "--voltage-v", "24", "--json"],
    )
    assert res.exit_code == 0, res.output
    cli = json.loads(res.output)
    api = _python(
        "import thrustmap\n"
        "p = thrustmap.predict(thrustmap.load_map('map.json'), thrust_n=4.2, voltage_v=24.0)\n"
        "print(p.throttle_pct, p.interval_pct)\n",
        cwd=tmp_path,
    ).split()
    assert float(api[0]) == pytest.approx(cli["throttle_pct"], rel=1e-12)
    assert float(api[1]) == pytest.approx(cli["interval_pct"], rel=1e-9)


def test_save_map_never_overwrites_an_input(tmp_path: Path) -> None:
    import thrustmap
    from thrustmap.core.errors import ConfigError

    tmap = thrustmap.load_map(ROOT / "fixtures" / "flightlogs" / "sim_map.json")
    log = tmp_path / "run.csv"
    log.write_text("recorded\n")
    with pytest.raises(ConfigError):
        thrustmap.save_map(tmap, log, inputs=[log])
    assert log.read_text() == "recorded\n"


def test_predict_questions_a_thrust_that_cannot_be_physical() -> None:
    import thrustmap
    from thrustmap.core.errors import ConfigError

    tmap = thrustmap.load_map(ROOT / "fixtures" / "flightlogs" / "sim_map.json")
    with pytest.raises(ConfigError):
        thrustmap.predict(tmap, thrust_n=float("nan"), voltage_v=16.0)
    with pytest.raises(ConfigError):
        thrustmap.predict(tmap, thrust_n=4.0, voltage_v=-3.0)
