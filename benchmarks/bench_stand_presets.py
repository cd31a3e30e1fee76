"""DIY line-stand presets (issue 43): a sweep on each preset's simulated stand, fitted and scored
against the simulator's truth, and the calibrations found on the real-firmware recordings.

    python benchmarks/bench_stand_presets.py   (simulated clock: well under a minute)

- tiny-thrust-stand: ``thrustmap stand run`` (its own sweep, duty 0..190 of 255), the
  crazyflie-2.1 plant;
- victorhook-thruststand: ``thrustmap sweep steps`` 10..60 % step 10, dwell 2 s, the motor driven
  by a simulated Betaflight FC (the stand drives none);
- einsz-whoop and avenhaus-thrust-stand: ``sweep steps`` 10..60 % step 10 (dwell 2 and 3 s);
- mqtb-teststand and einsz-whoop SWEEP: ``stand run``, the firmware's own program.
Every plant but the tiny stand's is xnova-2207-6s. einsz's throttle is the firmware's percent
label, DShot ``map(pct, 1, 100, 1, 2000)``: its truth is converted the same way; the others'
are percent of their scale.

Each log is fitted with the defaults and scored as mean and max |map - truth| in % throttle at
its steady points above 5 % of its top thrust (``tests/support/plant_truth.py``, the scoring the
tests use). Acceptance: within 1 % (mean). The recordings' calibrations
(``fixtures/stands/*/cal.json``) are printed beside the counts per gram the harness set.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))  # support.plant_truth: the tests' scoring
from support.plant_truth import ToPct, einsz_label, fit_error_vs_truth, percent_of_scale  # noqa: E402

STEPS = ["--from", "10", "--to", "60", "--step", "10"]


@dataclass(frozen=True)
class Run:
    preset: str
    plant: str
    args: list[str]  # the command, before --yes and -o
    to_pct: ToPct = percent_of_scale


def _sweep(preset: str, dwell: str, *extra: str) -> list[str]:
    url = f"sim://line-stand?preset={preset}"
    return ["sweep", "steps", "--stand", url, *extra, *STEPS, "--dwell", dwell, "-q"]


def _stand_run(preset: str, plant: str = "", *extra: str) -> list[str]:
    url = f"sim://line-stand?preset={preset}" + (f"&plant={plant}" if plant else "")
    return ["stand", "run", url, "--line-preset", preset, *extra]


#: the simulated MQTB and einsz programs reach 40,003-40,162 rpm, past the default 40,000 rpm
#: limit (which stops them, as it should): their runs raise it, as their tests do
HIGH_RPM = ("--max-rpm", "60000")


RUNS = {
    "tiny-thrust-stand": Run(
        "tiny-thrust-stand", "crazyflie-2.1", _stand_run("tiny-thrust-stand", "crazyflie-2.1")
    ),
    "victorhook-thruststand": Run(
        "victorhook-thruststand",
        "xnova-2207-6s",
        _sweep("victorhook-thruststand", "2", "--throttle", "sim://betaflight"),
    ),
    "einsz-whoop": Run("einsz-whoop", "xnova-2207-6s", _sweep("einsz-whoop", "2"), einsz_label),
    "avenhaus-thrust-stand": Run(
        "avenhaus-thrust-stand", "xnova-2207-6s", _sweep("avenhaus-thrust-stand", "3")
    ),
    "mqtb-teststand": Run(
        "mqtb-teststand", "xnova-2207-6s", _stand_run("mqtb-teststand", "", *HIGH_RPM)
    ),
    "einsz-whoop SWEEP": Run(
        "einsz-whoop", "xnova-2207-6s", _stand_run("einsz-whoop", "", *HIGH_RPM), einsz_label
    ),
}
SET_COUNTS_PER_GRAM = {"tiny-thrust-stand": -422.0, "victorhook-thruststand": -400.0}


def main() -> None:
    from thrustmap.core.physical import G0
    from thrustmap.rig.stand.line_calibration import load_line_calibration

    print(f"{'preset':<24} {'points':>6} {'mean %':>7} {'max %':>6}  (acceptance: mean < 1 %)")
    with tempfile.TemporaryDirectory() as tmp:
        for name, run in RUNS.items():
            out = Path(tmp) / f"{name.replace(' ', '-')}.csv"
            r = subprocess.run(
                [sys.executable, "-m", "thrustmap", *run.args, "--yes", "-o", str(out)],
                capture_output=True, text=True, cwd=ROOT,
            )  # fmt: skip
            if r.returncode != 0:
                print(f"{name:<24} failed: {(r.stderr or r.stdout).strip()}")
                continue
            mean, worst, n = fit_error_vs_truth(out, run.plant, run.to_pct)
            print(f"{name:<24} {n:>6} {mean:>7.2f} {worst:>6.2f}")
    print(f"\n{'recording':<24} {'found counts/g':>15} {'set':>7}")
    for name, set_value in SET_COUNTS_PER_GRAM.items():
        cal = load_line_calibration(ROOT / "fixtures" / "stands" / name / "cal.json")
        print(f"{name:<24} {cal.counts_per_n * G0 / 1000.0:>15.2f} {set_value:>7.1f}")


if __name__ == "__main__":
    main()
