"""Issue 23 acceptance on a generated fleet of 200+ logs (small logs: the whole test is seconds).

Every good log extracted, every corrupt one listed with its reason; per-airframe γ(B) equal to
`gamma fit` on that group's Df files; small and narrow groups reported, not fitted; a second
run with nothing new in under 5 % of the first run's time; the HTML report lists it all.
"""

from __future__ import annotations

import html
import json
import time
from pathlib import Path
from typing import Any

import pytest
from support.fleet_gen import AIRFRAMES, FEW, NARROW, Fleet, make_fleet

from thrustmap.cli import main
from thrustmap.fleet.table import read_table

pytest.importorskip("pyarrow")

LOGS_PER_AIRFRAME = 50  # 4 airframes × 50 + 6 narrow + 2 few + 1 without mass + 4 corrupt = 213
#: least squares keeps the 50-fold degree choice of each group fast; test_fleet.py checks the
#: default l1 (a linear program per fold) on a small fleet the same way
LOSS = "l2"


def cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    try:
        main(args)
    except SystemExit as exc:
        out, err = capsys.readouterr()
        raise AssertionError(f"exit {exc.code}: {err}") from None
    return capsys.readouterr().out


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Fleet:
    return make_fleet(tmp_path_factory.mktemp("fleet200"), LOGS_PER_AIRFRAME,
                      extra={NARROW: 6, FEW: 2})  # fmt: skip


def test_a_fleet_of_200_logs(
    fleet: Fleet, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    total = len(fleet.good) + len(fleet.corrupt) + len(fleet.no_mass)
    assert total >= 200
    out = tmp_path / "out"
    extract = ["fleet", "extract", str(fleet.folder), "-o", str(out), "--masses",
               str(fleet.masses_csv), "--map", str(fleet.stand_map), "--workers", "0", "--quiet"]  # fmt: skip
    t0 = time.perf_counter()
    cli(extract, capsys)
    first_s = time.perf_counter() - t0
    rows = {Path(o.path): o for o in read_table(out / "fleet.parquet")}
    assert len(rows) == total
    for path in fleet.good:
        o = rows[path.absolute()]
        assert o.status == "ok" and o.samples > 50 and (out / o.df_path).is_file(), o.reason
    for path, word in fleet.corrupt.items():
        o = rows[path.absolute()]
        assert o.status == "refused" and word in o.reason and str(path.absolute()) in o.reason

    # nothing new: every log skipped, in under 5 % of the first run's time
    t0 = time.perf_counter()
    stdout = cli(extract, capsys)
    second_s = time.perf_counter() - t0
    assert f"{total} already done" in stdout
    assert second_s < 0.05 * first_s, (first_s, second_s)

    # per-airframe γ(B)
    report = tmp_path / "fleet.html"
    summary = json.loads(
        cli(
            [
                "fleet",
                "gamma",
                str(out),
                "--map",
                str(fleet.stand_map),
                "-o",
                str(report),
                "--json",
                "--loss",
                LOSS,
            ],
            capsys,
        )  # fmt: skip
    )
    by_name: dict[str, dict[str, Any]] = {}
    for g in summary:
        names = {Path(p).name.split("-")[0] for p in g["logs"]}
        assert len(names) == 1, names  # one generated airframe per group, and back
        by_name[names.pop()] = g
    assert set(by_name) == {af.name for af in (*AIRFRAMES, NARROW, FEW)}
    assert by_name["narrow"]["status"] == "too narrow" and "spans" in by_name["narrow"]["reason"]
    assert by_name["few"]["status"] == "too small" and "2 logs" in by_name["few"]["reason"]
    for af in AIRFRAMES:
        g = by_name[af.name]
        assert g["status"] == "fitted" and len(g["logs"]) == LOGS_PER_AIRFRAME
        # `gamma fit` on the group's Df files gives the same γ(B)
        alone = json.loads(
            cli(
                [
                    "gamma",
                    "fit",
                    *g["df"],
                    "--map",
                    str(fleet.stand_map),
                    "-o",
                    str(tmp_path / f"{af.name}.json"),
                    "--json",
                    "--loss",
                    LOSS,
                ],
                capsys,
            )  # fmt: skip
        )
        assert g["gamma"]["degree"] == alone["degree"]
        assert g["gamma"]["coefficients"] == pytest.approx(alone["coefficients"], abs=1e-9, rel=0)
        # and the fleet's γ is the airframe's true one within 2 % over the flown voltage
        lo, hi = g["voltage_v"]
        for b in (lo, (lo + hi) / 2, hi):
            ours = sum(c * b**k for k, c in enumerate(g["gamma"]["coefficients"]))
            true = sum(c * b**k for k, c in enumerate(af.gamma))
            assert ours == pytest.approx(true, rel=0.02), (af.name, b)
        lo_band, hi_band = g["gamma_band_95"]
        assert lo_band < 0 < hi_band
        corrected = json.loads((out / "gamma" / f"{g['key']}.map.json").read_text())
        assert corrected["correction"]["coefficients"] == g["gamma"]["coefficients"]

    page = html.unescape(report.read_text(encoding="utf-8"))
    for g in summary:
        assert g["label"] in page
    assert f"Refused logs: {len(fleet.corrupt) + len(fleet.no_mass)}" in page
    assert "give the vehicle mass (--mass-kg): the log does not record it" in page
    assert "flight log is empty (N bytes)" in page
