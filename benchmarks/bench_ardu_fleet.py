"""Old ArduCopter fleet: clean Df samples per flight with the 3.2-3.4 rules, against 716adde.

Issue 34 item 2: of the real flights of a 2014-2016 fleet of ArduCopter DataFlash logs (mostly
3.3-dev builds on PXF/Erle boards), how many give ≥ 100 clean Df samples. The logs are not in
the repository (public logs gathered by hand, e.g. the erlerobot/logs repository); give their
folder(s) or files:

    python benchmarks/bench_ardu_fleet.py /data/ardu [--split split.json]

A flight: an ArduCopter log whose barometer (CTUN.BarAlt / BAlt) shows at least 20 s above
1.5 m over its level at the start while the command is above 0.2 (a log that never left the
ground is not one); copies of the same content count once. One whose accelerometer does not
shake as turning rotors shake it is named below the table (a bench test with the propellers
off whose barometer drifted as the board warmed?) but still counted. ``--split`` is a
JSON ``{"dev": [paths], "holdout": [paths]}``: the logs the rules were developed on and those
set aside, reported apart. Every flight gets ``DfOptions(mass_kg=1.5)`` (the mass changes no
filter). Baseline: the sample count the same file gave at 716adde (recorded by content hash
here; "—" for a file not recorded), printed beside ours, and which of the rules of
docs/old-arducopter.md fired.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from thrustmap.core.errors import ConfigError, DataFormatError  # noqa: E402
from thrustmap.fitting.df.extraction import extract  # noqa: E402
from thrustmap.fitting.df.options import DfOptions  # noqa: E402
from thrustmap.flightlogs import dataflash  # noqa: E402
from thrustmap.flightlogs.detect import read_log  # noqa: E402

#: clean Df samples at 716adde (issue 34's "before"), by the first 12 hex digits of SHA-256
BASELINE_716ADDE = {
    "05060bc28530": 729, "109654e93c1f": 0, "13cffbaf95d8": 520, "175faf944437": 0,
    "1b1c6d780411": 396, "286e2ecd06f2": 33, "2dbf6e570046": 1799, "2e506a406c65": 995,
    "2f564baf3146": 22, "3fae98243011": 1, "41b9ecf8dd27": 42, "433039559645": 25,
    "58ac513f6b33": 0, "5a0fcd318891": 0, "5a60e49c9c3b": 0, "5c1a5952c00c": 238,
    "5d19528c3180": 621, "6cf8e2e22790": 0, "7220a2d8d849": 0, "780948991dd6": 0,
    "7cdb63ca4e42": 1314, "803c10cf5059": 1378, "8053394e67b2": 1229, "883edb95d20c": 2005,
    "97da4335ca0c": 642, "a439b3603b5b": 1173, "a49372f9a84b": 181, "a54f53c1ec72": 44,
    "abf755937656": 42, "ae7f8a0273d7": 0, "af685aab085d": 428, "b0fc3c4badb2": 2115,
    "b71a97259af2": 1, "b7d62e998453": 89, "c64e3b366719": 2699, "d20e3d90f4f9": 712,
    "e8ca56c15499": 2135, "ea503ce26cc9": 89, "fc7734f83b54": 549,
}  # fmt: skip
RULES = ("inav-baro", "climb-crt", "accelerometer calibrated", "events untimed")
MIN_SAMPLES = 100


#: rotors turning shake the accelerometer by more than this (m/s², standard deviation of -IMU.AccZ
#: within a second, median over the seconds the command is above 0.2): the steadiest real flight
#: here reads 0.10, a board on a bench with its propellers off 0.03 (flagged, still counted)
ROTOR_VIBRATION_MPS2 = 0.05


def flight_seconds(path: Path) -> tuple[float, float] | None:
    """Seconds the barometer shows the vehicle 1.5 m up with the command above 0.2, and how
    much the accelerometer shakes while the command is above 0.2 (None: not an ArduCopter log
    with CTUN)."""
    try:
        log = dataflash.parse(path)
    except Exception:
        return None
    fw = next((m for m in log.text_messages() if m.startswith(("APM:", "Ardu"))), "")
    if "Copter" not in fw or not log.has("CTUN"):
        return None
    c = log.columns("CTUN")
    baro = next((k for k in ("BarAlt", "BAlt") if k in c), None)
    thr_col = next((k for k in ("ThrOut", "ThO") if k in c), None)
    if baro is None or thr_col is None:
        return None
    t = log.time_s("CTUN")
    b = np.asarray(c[baro], float)
    thr = np.asarray(c[thr_col], float)
    thr = thr / (1000.0 if thr.max() > 2 else 1.0)
    ground = float(np.median(b[: max(5, len(b) // 20)]))
    up_s = float(((b - ground >= 1.5) & (thr > 0.2)).sum() * np.median(np.diff(t)))
    shake = float("nan")
    if log.has("IMU"):
        ti, acc = log.time_s("IMU"), -np.asarray(log.columns("IMU")["AccZ"], float)
        on = np.interp(ti, t, thr) > 0.2
        sec = np.floor(ti[on]).astype(np.int64)  # the shaking within each second, median
        stds = [float(np.std(acc[on][sec == k])) for k in np.unique(sec)]
        shake = float(np.median(stds)) if stds else shake
    return up_s, shake


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sources", nargs="+", type=Path, help="folders or DataFlash files")
    ap.add_argument("--split", type=Path, help='JSON {"dev": [...], "holdout": [...]}')
    ap.add_argument("--why", action="store_true",
                    help="for a flight under the target, the filter steps that dropped most")  # fmt: skip
    a = ap.parse_args()
    files = sorted(
        p for s in a.sources for p in ([s] if s.is_file() else s.rglob("*")) if p.is_file()
    )
    part: dict[str, str] = {}
    if a.split:
        split = json.loads(a.split.read_text())
        part = {str(Path(p).resolve()): k for k, ps in split.items() for p in ps}
    seen: set[str] = set()
    rows: list[tuple[str, str, int, int | None, list[str]]] = []
    benches: list[str] = []
    for p in files:
        digest = hashlib.sha256(p.read_bytes()).hexdigest()[:12]
        if digest in seen:
            continue
        found = flight_seconds(p)
        if found is None or found[0] < 20.0:
            continue
        seen.add(digest)
        group, base = part.get(str(p.resolve()), "all"), BASELINE_716ADDE.get(digest)
        if not found[1] > ROTOR_VIBRATION_MPS2:  # the barometer drifted; nothing flew?
            benches.append(p.name)
        try:
            df = extract(read_log(p), DfOptions(mass_kg=1.5))
        except (DataFormatError, ConfigError) as exc:  # refused: a row saying why, not a crash
            rows.append((group, p.name, 0, base, [f"REFUSED: {exc}"]))
            continue
        fired = [r for r in RULES if any(w.startswith(r) for w in df.reports[0].warnings)]
        steps = {s.name: s.dropped_s for s in df.reports[0].steps}
        if steps.get("log-pause", 0.0) > 0:
            fired.append(f"log-pause {steps['log-pause']:.0f} s")
        if a.why and len(df) < MIN_SAMPLES:
            worst = sorted(steps.items(), key=lambda kv: -kv[1])[:4]
            fired.append("dropped: " + ", ".join(f"{k} {v:.0f} s" for k, v in worst if v > 0))
        rows.append((group, p.name, len(df), base, fired))
    print(f"{'part':8s} {'flight':44s} {'716adde':>8s} {'now':>6s}  rules that fired")
    for group, name, n, base, fired in sorted(rows):
        shown = "—" if base is None else str(base)
        print(f"{group:8s} {name[:44]:44s} {shown:>8s} {n:6d}  {', '.join(fired)}")
    for group in sorted({r[0] for r in rows}):
        sel = [r for r in rows if r[0] == group]
        now = sum(r[2] >= MIN_SAMPLES for r in sel)
        base = sum((r[3] or 0) >= MIN_SAMPLES for r in sel)
        print(f"{group}: {len(sel)} flights; ≥ {MIN_SAMPLES} clean samples: 716adde {base}, "
              f"now {now}")  # fmt: skip
    for name in benches:
        print(f"{name}: -IMU.AccZ shakes ≤ {ROTOR_VIBRATION_MPS2:g} m/s² with the command above "
              "0.2: a bench test with the propellers off? (counted as a flight)")  # fmt: skip
    now = sum(r[2] >= MIN_SAMPLES for r in rows)
    base = sum((r[3] or 0) >= MIN_SAMPLES for r in rows)
    print(f"all: {len(rows)} flights; ≥ {MIN_SAMPLES} clean samples: 716adde {base}, now {now} "
          f"(issue 34's target: ≥ 30 of 36)")  # fmt: skip


if __name__ == "__main__":
    main()
