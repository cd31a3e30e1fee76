"""`flightlog extract` on a ULog loads only what it uses: the vectorised reader needs numpy
alone (pyulog only for what it declines), and writing the Df needs no tempfile (its imports of
random, shutil and the compressors cost ~15 ms of CPU at every start). Issue 34 asks the whole
process to stay within 1.1x a plain pyulog load; benchmarks/bench_flightlogs.py measures it."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from support import simulate_flight as simulate

NOT_NEEDED = ("pyulog", "tempfile", "shutil", "random", "pandas", "scipy")

PROBE = """
import json, sys
from thrustmap.cli import main
try:
    main({argv!r})
except SystemExit as exc:
    code = exc.code
else:
    code = 0
loaded = sorted({{m.split('.')[0] for m in sys.modules}} & set({names!r}))
sys.stderr.write("LOADED=" + json.dumps([code, loaded]) + "\\n")
"""


def test_ulog_extract_loads_neither_pyulog_nor_tempfile(tmp_path: Path) -> None:
    flight = simulate.simulate_hover(simulate.HoverSim(duration_s=30.0, rate_hz=100.0))
    log = tmp_path / "hover.ulg"
    simulate.write_ulog(flight, log)
    out = tmp_path / "df.csv"
    argv = ["flightlog", "extract", str(log), "--mass-kg", "1.5", "-o", str(out)]
    res = subprocess.run(
        [sys.executable, "-c", PROBE.format(argv=argv, names=list(NOT_NEEDED))],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    line = [x for x in res.stderr.splitlines() if x.startswith("LOADED=")]
    assert line, res.stderr
    code, loaded = json.loads(line[-1][len("LOADED=") :])
    assert code in (0, None), res.stderr
    assert loaded == []
    rows = out.read_text().splitlines()
    assert len(rows) > 10  # the Df was written (header + samples), atomically, beside its sidecar
    assert json.loads(out.with_suffix(".json").read_text())["logs"][0]["path"] == str(log)
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]
