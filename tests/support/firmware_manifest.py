"""Write fixtures/firmware/<fw>/MANIFEST.json: every recording's size, sha256, claim and command.

    python -m support.firmware_manifest FOLDER --fw ardupilot|px4 --name ArduCopter \
        --version 4.7.0-dev --commit SHA --source URL [--flight-log flight.BIN --mass-kg 3.0]

tests/test_firmware_recordings.py checks every file against it (and that no file is missing
from it). Run again after re-recording; it keeps nothing from an older manifest.
"""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path
from typing import Any

RECORD = "python -m support.record_firmware {fw} {binary} {out}"
FLIGHT = "python -m support.sitl_flight {fw} {binary} {out} --hover-s 30"
CLAIMS = {
    "probe": "identification (probe) over udpin",
    "probe_signed": "signed MAVLink accepted: probe with --signing-key after SETUP_SIGNING",
    "probe_unsigned": "unsigned MAVLink refused: probe without a key after SETUP_SIGNING",
    "spin": "motor test stop: the end of the spin",
    "spin_sigint": "motor test stop: Ctrl-C (SIGINT) while the motor turns",
    "spin_sigterm": "motor test stop: SIGTERM while the motor turns",
    "spin_sigkill": "motor test stop: thrustmap killed (SIGKILL), the firmware ends the test",
    "spin_lostlink": "motor test stop: the link cut both ways, the firmware ends the test",
    "spin_intruder": "locked link: a second sender stops the spin (exit 1), never answered",
}
KINDS = {
    ".jsonl": "thrustmap's record:// transcript (host and firmware bytes)",
    ".json": "the recording run's outcome (exit code, output, intruder counts)",
    ".monitor.tlog": "the vehicle's own report on another port (HEARTBEAT, SERVO_OUTPUT_RAW, "
    "STATUSTEXT, COMMAND_ACK)",
}


def _entry(path: Path, fw: str, flight_log: str, binary: str) -> dict[str, Any]:
    data = path.read_bytes()
    name = path.name
    entry: dict[str, Any] = {
        "file": name,
        "bytes": len(data),
        "sha256": hashlib.sha256(data).hexdigest(),
    }
    if name.startswith("flight.logdf"):
        entry["claim"] = "γ live on a flown hover vs gamma fit on the firmware's own log"
        entry["command"] = FLIGHT.format(fw=fw, binary=binary, out="/work/build/flight/" + fw) + (
            "; then python -m thrustmap flightlog extract <its .ulg> --map map.json --mass-kg 1.0"
            " -o flight.logdf.csv"
        )
        entry["kind"] = (
            "the Df flightlog extract took from the firmware's whole log (not committed)"
        )
        return entry
    if name.startswith("flight"):
        trim = {
            "flight.tlog": "trim_logs tlog live.tlog flight.tlog",
            "flight.map.json": "the stand map sitl_flight wrote (map.json)",
        }.get(name, f"trim_logs {'dataflash' if fw == 'ardupilot' else 'ulog'} <log> {name}")
        entry["claim"] = "γ live on a flown hover vs gamma fit on the firmware's own log"
        entry["command"] = FLIGHT.format(fw=fw, binary=binary, out="/work/build/flight/" + fw) + (
            f"; then python -m support.{trim}"
        )
        entry["kind"] = "the firmware's own log, trimmed" if name == flight_log else "telemetry"
        return entry
    stem = name.split(".")[0]
    kind = next(k for k in (".monitor.tlog", ".jsonl", ".json") if name.endswith(k))
    entry["claim"] = CLAIMS[stem]
    entry["kind"] = KINDS[kind]
    entry["command"] = RECORD.format(fw=fw, binary=binary, out="/work/build/rec/" + fw)
    return entry


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("folder", type=Path)
    ap.add_argument("--fw", required=True, choices=["ardupilot", "px4"])
    ap.add_argument("--name", required=True)
    ap.add_argument("--version", required=True)
    ap.add_argument("--commit", required=True)
    ap.add_argument("--source", required=True)
    ap.add_argument("--recorded", required=True, help="UTC date of the recording")
    ap.add_argument("--binary", required=True, help="the SITL binary, as recorded")
    ap.add_argument("--flight-log", default="")
    ap.add_argument("--flight-log-df", default="", help="instead of the log: its Df (CSV)")
    ap.add_argument("--log-sha256", default="", help="sha256 of the log behind --flight-log-df")
    ap.add_argument("--log-bytes", type=int, default=0)
    ap.add_argument("--mass-kg", type=float, default=0.0)
    ap.add_argument("--gamma-tolerance", type=float, default=0.01)
    ap.add_argument("--min-voltage-span-v", type=float, default=0.05)
    a = ap.parse_args()
    skip = {"MANIFEST.json", "README.md"}
    files = sorted(p for p in a.folder.iterdir() if p.is_file() and p.name not in skip)
    manifest: dict[str, Any] = {
        "firmware": {
            "name": a.name,
            "version": a.version,
            "commit": a.commit,
            "source": a.source,
            "recorded_utc": a.recorded,
        },
        "recording": [_entry(p, a.fw, a.flight_log, a.binary) for p in files],
    }
    if a.flight_log or a.flight_log_df:
        manifest["flight"] = {
            "log": a.flight_log,
            "log_df": a.flight_log_df,
            "log_sha256": a.log_sha256,
            "log_bytes": a.log_bytes,
            "mass_kg": a.mass_kg,
            "gamma_tolerance": a.gamma_tolerance,
            "min_voltage_span_v": a.min_voltage_span_v,
        }
    (a.folder / "MANIFEST.json").write_text(
        json.dumps(manifest, indent=1, ensure_ascii=False) + "\n"
    )
    (a.folder / "README.md").write_text(readme(manifest))


def readme(manifest: dict[str, Any]) -> str:
    fw = manifest["firmware"]
    lines = [
        f"# {fw['name']} {fw['version']}: recordings of the real firmware",
        "",
        f"Built from {fw['source']} at commit `{fw['commit']}`, recorded {fw['recorded_utc']} as",
        "SITL on loopback in a private network namespace. Replayed in CI by",
        "`tests/test_firmware_recordings.py`, which checks each file's sha256 against",
        "`MANIFEST.json` (machine-readable: the same lines plus each file's kind). Commands run",
        "from `tests/` (how to re-record: docs/howto/flight-controllers.md).",
        "",
        "| file | bytes | sha256 | claim | recorded by |",
        "|---|---|---|---|---|",
    ]
    for r in manifest["recording"]:
        lines.append(
            f"| `{r['file']}` | {r['bytes']} | `{r['sha256']}` | {r['claim']} | `{r['command']}` |"
        )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
