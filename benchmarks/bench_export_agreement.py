"""One number per question (issue 40 item 2): the full-throttle thrust every export writes for
the demo's maps, whether it names it extrapolated, and what holding each firmware's curve to it
costs inside the data (the curve-vs-map RMS each export prints), beside the same figures from
19a0a12, where each firmware's curve extrapolated on its own.

Runs ``thrustmap demo`` into a temporary folder (about 6 s), then exports its single-rotor and
multi-rotor maps to every firmware target with the defaults and reads the values back from the
export itself. The acceptance: every export of a map agrees on the full-throttle thrust within
0.5 % and names it extrapolated with its interval.

    python benchmarks/bench_export_agreement.py [--demo DIR]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from thrustmap.fitting.export.encodings import ExportOptions
from thrustmap.fitting.export.targets import export_map
from thrustmap.fitting.mapfile import ThrustMap
from thrustmap.fitting.mapvalues import map_values

TARGETS = [
    ("px4", "px4", ExportOptions()),
    ("ardupilot", "ardupilot", ExportOptions()),
    ("betaflight 4.6", "betaflight", ExportOptions(firmware="4.6")),
    ("betaflight 2026.6", "betaflight", ExportOptions(firmware="2026.6")),
    ("dshot (encoding)", "dshot", ExportOptions()),
    ("c-header", "c-header", ExportOptions()),
    ("aerostack2", "aerostack2", ExportOptions()),
]
#: the demo's single-rotor map on 19a0a12: the full-throttle thrust each export implied (its
#: curve at the top of the output range: PX4 and Betaflight T_max, ArduPilot's thrust at u = 1)
#: and its curve-vs-map RMS, % of the output range; none said it was extrapolated
BASELINE_SR = {
    "px4": (20.0, 0.119),
    "ardupilot": (16.8, 0.816),
    "betaflight 4.6": (18.25, 2.80),
    "betaflight 2026.6": (21.65, 3.04),
}


def _row(
    tmap: ThrustMap, label: str, target: str, opts: ExportOptions
) -> tuple[list[str], float | None]:
    res = export_map(tmap, target, opts)
    full = res.values.get("full_throttle_thrust_n")
    head = res.text.split("written values outside the supported region")[0]
    named = any("full-throttle thrust at" in ln and "EXTRAPOLATED" in ln and "interval" in ln
                for ln in head.splitlines())  # fmt: skip
    rms = res.residual.get("rms_pct")
    cells = [
        label,
        "-" if full is None else f"{full:.4g}",
        "yes" if named else "no",
        "-" if rms is None else f"{rms:.3g}",
    ]
    return cells, full


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--demo", type=Path, help="a `thrustmap demo` output folder (else run one)")
    args = ap.parse_args()
    tmp = None
    folder = args.demo
    if folder is None:
        from thrustmap.demo import run_demo

        tmp = tempfile.TemporaryDirectory()
        folder = Path(tmp.name)
        run_demo(folder, parallel=False)
    worst = 0.0
    for name in ("sr-map.json", "mr-map.json"):
        tmap = ThrustMap.load(folder / name)
        full = map_values(tmap).full_throttle
        assert full is not None
        print(f"\n{name}: {full.line()}")
        print(f"{'export':20} {'full N':>8} {'named':>6} {'RMS %':>7}   19a0a12: full N, RMS %")
        for label, target, opts in TARGETS:
            row, value = _row(tmap, label, target, opts)
            base = BASELINE_SR.get(label) if name == "sr-map.json" else None
            was = f"   {base[0]:g}, {base[1]:g} (not named)" if base else ""
            print(f"{row[0]:20} {row[1]:>8} {row[2]:>6} {row[3]:>7}{was}")
            if value is not None:
                worst = max(worst, abs(value / full.value - 1.0))
    print(f"\nlargest disagreement with the map's value: {100 * worst:.3f} % (acceptance 0.5 %)")
    if tmp is not None:
        tmp.cleanup()
    return 0 if worst <= 0.005 else 1


if __name__ == "__main__":
    sys.exit(main())
