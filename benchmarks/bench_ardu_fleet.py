"""Old ArduCopter fleet: clean Df samples per flight with the 3.2-3.4 rules, against 716adde.

Issue 34 item 2: of the real flights of a 2014-2016 fleet of ArduCopter DataFlash logs (mostly
3.3-dev builds on PXF/Erle boards), how many give ≥ 100 clean Df samples. The logs are not in
the repository: the 39 flights of the public erlerobot/logs repository are pinned by name,
commit, path and sha256 in benchmarks/public-data.toml (placed under THRUSTMAP_PUBLIC_DATA):

    python benchmarks/bench_ardu_fleet.py --manifest [--why]
    python benchmarks/bench_ardu_fleet.py FOLDER_OR_FILE ... [--why]

With folders or files, a flight is an ArduCopter log whose barometer (CTUN.BarAlt / BAlt) shows
at least 20 s above 1.5 m over its level at the start while the command is above 0.2 (a log that
never left the ground is not one); copies of the same content count once; a file the manifest
pins takes its manifest name and role. One whose accelerometer does not shake as turning rotors
shake it is named below the table (a bench test with the propellers off whose barometer drifted
as the board warmed?) but still counted. The role column is the manifest's (development or
set-aside); every erlerobot flight is development (the manifest says why). Every flight gets
``DfOptions(mass_kg=1.5)`` (the mass changes no filter). Baseline: the sample count the same
file gave at 716adde ("—" for a file the manifest does not pin), printed beside ours, and which
of the rules of docs/old-arducopter.md fired. tests/test_ardu_fleet_public.py checks the counts.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))  # support.public_data: the manifest's files by name

import numpy as np  # noqa: E402
from support import public_data as pd  # noqa: E402

from thrustmap.core.errors import ConfigError, DataFormatError  # noqa: E402
from thrustmap.fitting.df.extraction import extract  # noqa: E402
from thrustmap.fitting.df_options import DfOptions  # noqa: E402
from thrustmap.flightlogs import dataflash  # noqa: E402
from thrustmap.flightlogs.detect import read_log  # noqa: E402

#: clean Df samples at 716adde (issue 34's "before"), by manifest name (benchmarks/public-data.toml);
#: reproduced on 2026-11-28 with 716adde's own code: ``git worktree add /tmp/t 716adde`` and, per
#: file, ``len(extract(read_log(path), DfOptions(mass_kg=1.5)))`` with that tree on sys.path
BASELINE_716ADDE = {
    "erle/09-10-2014_25": 1314, "erle/09-10-2014_30": 621, "erle/09-10-2014_31": 2135,
    "erle/10-11-2014_103": 729, "erle/10-11-2014_104": 642, "erle/10-11-2014_105": 0,
    "erle/11-2-2015_112": 1173, "erle/14-11-2014_118": 1378, "erle/15-10-2014_42": 89,
    "erle/15-10-2014_44": 0, "erle/15-12-2014_16": 1229, "erle/18-03-2014_althold_error": 0,
    "erle/18-03-2014_althold_error2": 0, "erle/19-10-2014_ALT_HOLD_test1": 2005,
    "erle/20-10-2014_land_mode_test1": 396, "erle/22-12-2014_41": 0, "erle/23-9-2014_52": 1,
    "erle/25-9-2014_3": 238, "erle/26-11-2014_181": 428, "erle/29-09-2014_1": 44,
    "erle/29-09-2014_2": 0, "erle/29-09-2014_4": 33, "erle/30-3-2015_73": 89,
    "erle/31-3-2015_83": 0, "erle/5-12-2014_218": 2699, "erle/6-11-2014_GPS_issues1": 520,
    "erle/6-11-2014_GPS_issues2": 712, "erle/6-11-2014_GPS_issues3": 549,
    "erle/6-11-2014_Loiter_RTL": 1799, "erle/6-3-2014_7": 42, "erle/7-9-2014_21": 25,
    "erle/7-9-2014_24": 22, "erle/7-9-2014_25": 181, "erle/8-10-2014_11": 0,
    "erle/8-10-2014_18": 42, "erle/aux_baroexterno_bmp085": 1, "erle/aux_barointerno": 0,
    "erle/copter_Erle-Brain3": 2115, "erle/copter_PXFv2.0b+Rpi": 995,
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


def flights(a: argparse.Namespace) -> list[tuple[str, str, Path]]:
    """(role, name, file) of each flight: the manifest's erlerobot entries, or every distinct
    ArduCopter flight in the files given (named and given a role by the manifest when it pins
    their bytes)."""
    if a.manifest:
        pd.manifest()  # a broken manifest fails before anything runs
        return [
            (pd.manifest()[n].role, n, pd.resolve(n, a.public_data))
            for n in pd.names(source="erlerobot")
        ]
    by_sha = {e.sha256: e for e in pd.manifest().values()}
    files = sorted(
        p for s in a.sources for p in ([s] if s.is_file() else s.rglob("*")) if p.is_file()
    )
    out: list[tuple[str, str, Path]] = []
    seen: set[str] = set()
    for p in files:
        digest = hashlib.sha256(p.read_bytes()).hexdigest()
        if digest in seen:
            continue
        found = flight_seconds(p)
        if found is None or found[0] < 20.0:
            continue
        seen.add(digest)
        e = by_sha.get(digest)
        out.append((e.role, e.name, p) if e else ("—", p.name, p))
    return out


def score(role: str, name: str, path: Path, why: bool) -> tuple[str, str, int, list[str]]:
    """(role, name, clean Df samples, the rules that fired) of one flight; a refused file is a
    row saying why, never a crash."""
    try:
        df = extract(read_log(path), DfOptions(mass_kg=1.5))
    except (DataFormatError, ConfigError) as exc:
        return role, name, 0, [f"REFUSED: {exc}"]
    fired = [r for r in RULES if any(w.startswith(r) for w in df.reports[0].warnings)]
    steps = {s.name: s.dropped_s for s in df.reports[0].steps}
    if steps.get("log-pause", 0.0) > 0:
        fired.append(f"log-pause {steps['log-pause']:.0f} s")
    if why and len(df) < MIN_SAMPLES:
        worst = sorted(steps.items(), key=lambda kv: -kv[1])[:4]
        fired.append("dropped: " + ", ".join(f"{k} {v:.0f} s" for k, v in worst if v > 0))
    return role, name, len(df), fired


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sources", nargs="*", type=Path, help="folders or DataFlash files")
    ap.add_argument("--manifest", action="store_true",
                    help="the erlerobot flights of benchmarks/public-data.toml, by name")  # fmt: skip
    ap.add_argument("--public-data", type=Path,
                    help="the public-data folder (default: THRUSTMAP_PUBLIC_DATA, ...)")  # fmt: skip
    ap.add_argument("--why", action="store_true",
                    help="for a flight under the target, the filter steps that dropped most")  # fmt: skip
    a = ap.parse_args()
    if not a.manifest and not a.sources:
        ap.error("give --manifest or the folders/files of the logs")
    try:
        found = flights(a)
    except pd.PublicDataError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(2)
    rows, benches = [], []
    for role, name, path in found:
        shake = flight_seconds(path)
        if shake is not None and not shake[1] > ROTOR_VIBRATION_MPS2:  # nothing flew?
            benches.append(name)
        rows.append(score(role, name, path, a.why))
    print(f"{'role':11s} {'flight':36s} {'716adde':>8s} {'now':>6s}  rules that fired")
    for role, name, n, fired in sorted(rows):
        base = BASELINE_716ADDE.get(name)
        shown = "—" if base is None else str(base)
        print(f"{role:11s} {name[:36]:36s} {shown:>8s} {n:6d}  {', '.join(fired)}")
    for name in benches:
        print(f"{name}: -IMU.AccZ shakes ≤ {ROTOR_VIBRATION_MPS2:g} m/s² with the command above "
              "0.2: a bench test with the propellers off? (counted as a flight)")  # fmt: skip
    for role in sorted({r[0] for r in rows}) + ["all"]:
        sel = [r for r in rows if role in ("all", r[0])]
        now = sum(r[2] >= MIN_SAMPLES for r in sel)
        base = sum(BASELINE_716ADDE.get(r[1], 0) >= MIN_SAMPLES for r in sel)
        print(f"{role}: {len(sel)} flights; ≥ {MIN_SAMPLES} clean samples: 716adde {base}, "
              f"now {now}")  # fmt: skip


if __name__ == "__main__":
    main()
