"""Acceptance on the seed paper's own data: Table 3 reproduced, and held-out results."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from thrustmap.cli import main

PAPER_TABLE3 = {  # mean e_Th %, ../shared/data/README.md
    "single_rotor/xNova-TM-SR.csv": {
        "poly2": 1.541,
        "poly2-trunc": 1.543,
        "poly3": 1.411,
        "poly3-trunc": 1.494,
    },
    "multirotor/xNova-TM-MR.csv": {
        "poly2": 1.009,
        "poly2-trunc": 1.041,
        "poly3": 0.933,
        "poly3-trunc": 1.009,
    },
}
PAPER_FILTERS = [
    "--all-samples",
    "--loss",
    "l2",
    "--throttle-range",
    "1300:1500",
    "--voltage-range",
    "20.4:25.2",
    "--thrust-range",
    "0:11",
]


def run_json(args: list[str], capsys: pytest.CaptureFixture[str]) -> dict[str, object]:
    main(args)
    out: dict[str, object] = json.loads(capsys.readouterr().out)
    return out


@pytest.mark.parametrize("rel", sorted(PAPER_TABLE3))
def test_table3_reproduced(shared_data: Path, capsys: pytest.CaptureFixture[str], rel: str) -> None:
    path = shared_data / "xnova-thrust-stand" / rel
    expected = PAPER_TABLE3[rel]
    out = run_json(
        [
            "compare",
            str(path),
            "--models",
            ",".join(expected),
            "--validate",
            "in-sample",
            "--json",
            *PAPER_FILTERS,
        ],
        capsys,
    )
    rows = {r["model"]: r for r in out["rows"]}  # type: ignore[attr-defined]
    for model, paper_mean in expected.items():
        assert rows[model]["mean_pct"] == pytest.approx(paper_mean, abs=0.05), model


def test_default_model_beats_poly2_held_out_by_file(
    shared_data: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sr = shared_data / "xnova-thrust-stand" / "single_rotor"
    out = run_json(
        [
            "compare",
            str(sr / "xNova-SR-steps.csv"),
            str(sr / "xNova-SR-steps-up.csv"),
            "--models",
            "motor,poly2",
            "--validate",
            "by-file",
            "--json",
        ],
        capsys,
    )
    rows = {r["model"]: r for r in out["rows"]}  # type: ignore[attr-defined]
    inside = rows["motor"]["inside_box"]
    # 0.71 % with a map that obeys physics, each file read from its load cell's zero (the steps
    # file rests at 0.061 N, steps-up at 0.004 N); 1.11 % read raw, where at equal thrust the
    # lower-voltage file seemed to need LESS throttle, which no motor does; the 0.51 % before
    # came from a negative no-load term that crossed the voltage slices
    assert inside["mean_pct"] <= 0.75
    assert inside["n"] >= 60
    assert rows["poly2"]["inside_box"]["mean_pct"] > 5 * inside["mean_pct"]
    # the headline counts every held-out point; the split by the training box is beside it
    assert rows["motor"]["outside_box"]["n"] > 0
    assert rows["motor"]["n"] == inside["n"] + rows["motor"]["outside_box"]["n"]
    assert rows["motor"]["mean_pct"] <= 0.7
    assert rows["poly2"]["mean_pct"] > 5 * rows["motor"]["mean_pct"]


def test_fit_predict_roundtrip_on_real_data(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sr = shared_data / "xnova-thrust-stand" / "single_rotor"
    out_map = tmp_path / "sr.json"
    main(
        [
            "fit",
            str(sr / "xNova-SR-steps.csv"),
            str(sr / "xNova-SR-steps-up.csv"),
            "-o",
            str(out_map),
        ]
    )
    capsys.readouterr()
    doc = json.loads(out_map.read_text())
    assert doc["model"] == "motor" and doc["strategy"] in ("SR", "unknown")
    assert len(doc["sources"]) == 2 and all(len(s["sha256"]) == 64 for s in doc["sources"])
    pred = run_json(
        ["predict", str(out_map), "--thrust-n", "3.0", "--voltage-v", "22.0", "--json"], capsys
    )
    # real data: ~3.0 N needs ~1450 µs at 22 V on this rig
    assert 1420 < float(pred["throttle_native"]) < 1480  # type: ignore[arg-type]
    assert pred["throttle_pct"] == pytest.approx((float(pred["throttle_native"]) - 1000) / 10)  # type: ignore[arg-type]
    back = run_json(
        [
            "predict",
            str(out_map),
            "--throttle",
            str(pred["throttle_native"]),
            "--voltage-v",
            "22.0",
            "--json",
        ],
        capsys,
    )
    assert back["thrust_n"] == pytest.approx(3.0, rel=1e-6)
