"""Malformed inputs for the ``thrustmap`` commands, built from our own fixtures.

Each case writes its files into a folder and names the command line to run there. The issue-14
examples are all here (hangs, time jumps, outputs over inputs, hostile transcripts, internal
errors, unclear errors); the CLI test runs every case through :func:`thrustmap.cli.main` in a
bounded child process and accepts only exit 0, or exit 2 with exactly one stderr line.
"""

from __future__ import annotations

import contextlib
import json
import os
import pickle
import resource
import signal
import struct
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

FIXTURES = Path(__file__).resolve().parents[2] / "fixtures"
LOGS = FIXTURES / "flightlogs"
SWEEPS = FIXTURES / "sweeps"


@dataclass
class Case:
    name: str
    argv: list[str]
    files: dict[str, bytes] = field(default_factory=dict)
    #: exit codes accepted (0 and 2 by default); stderr of an exit-2 case must be one line
    codes: tuple[int, ...] = (0, 2)
    #: text the one stderr line must contain (when the case must fail)
    expect: str | None = None
    #: a check of the folder after the run (e.g. an input left untouched)
    after: Callable[[Path], None] | None = None
    #: seconds it may take (the hang examples must finish well inside the acceptance's 60 s)
    timeout_s: float = 60.0


@dataclass(frozen=True)
class CliResult:
    name: str
    code: int | None  # None: timed out / crashed
    stdout: str
    stderr: str
    seconds: float
    note: str = ""


# -- builders -------------------------------------------------------------------------------------


def bbl_with_header(replace: dict[str, str]) -> bytes:
    """The blackbox fixture with header lines replaced (``"I interval": "99999999"``)."""
    raw = (LOGS / "bb_hover_sim.bbl").read_bytes()
    out = []
    for line in raw.split(b"\n"):
        if line.startswith(b"H "):
            key = line[2:].split(b":", 1)[0].decode("latin-1")
            if key in replace:
                line = f"H {key}:{replace[key]}".encode("latin-1")
        out.append(line)
    return b"\n".join(out)


def bbl_many_fields(count: int) -> bytes:
    names = ",".join(f"f{i}" for i in range(count))
    zeros = ",".join("0" for _ in range(count))
    nulls = ",".join("0" for _ in range(count))
    return bbl_with_header(
        {
            "Field I name": "loopIteration,time," + names,
            "Field I signed": "0,0," + zeros,
            "Field I predictor": "0,0," + zeros,
            "Field I encoding": "1,1," + nulls,
            "Field P predictor": "6,2," + zeros,
            "Field P encoding": "9,0," + nulls,
        }
    )


def dataflash_many_breaks(target_bytes: int = 720_000) -> bytes:
    """The DataFlash fixture grown to ``target_bytes`` with a stray byte after every second
    message of the data part: a chain break every two messages (the quadratic-resync example)."""
    raw = (LOGS / "sim_hover.bin").read_bytes()
    # walk the chain using the FMT lengths
    lengths: dict[int, int] = {}
    pos = 0
    starts = []
    while pos + 3 <= len(raw) and raw[pos] == 0xA3 and raw[pos + 1] == 0x95:
        t = raw[pos + 2]
        if t == 128:
            lengths[raw[pos + 3]] = raw[pos + 4]
            lengths[128] = 89
        n = lengths.get(t)
        if not n:
            break
        starts.append((pos, n, t))
        pos += n
    head = b"".join(raw[p : p + n] for p, n, t in starts if t == 128)
    body = [raw[p : p + n] for p, n, t in starts if t != 128]
    out = bytearray(head)
    i = 0
    while len(out) < target_bytes and body:
        out += body[i % len(body)] + body[(i + 1) % len(body)] + b"\x00"
        i += 2
    return bytes(out)


def ulog_hang(size: int = 12000) -> bytes:
    """A ULog header, then a message of unknown type one byte longer than the rest of the file:
    pyulog 1.3 reads it short, seeks back 2 + size bytes to the same header and loops forever."""
    raw = (LOGS / "sim_hover.ulg").read_bytes()
    return raw[:16] + struct.pack("<HB", size, 1) + b"\x07" * (size - 1)


def ulog_flipped(seed: int, flips: int = 17) -> bytes:
    import random

    rng = random.Random(seed)
    buf = bytearray((LOGS / "sim_hover.ulg").read_bytes())
    for _ in range(flips):
        i = rng.randrange(16, len(buf))
        buf[i] ^= 1 << rng.randrange(8)
    return bytes(buf)


def paper_csv_time_typo(value: str = "3005000") -> bytes:
    """The seed-paper CSV with one time mistyped (the 48 s / 4.2 GB example)."""
    lines = (LOGS / "sim_hover_paper.csv").read_bytes().split(b"\n")
    header = lines[0].decode().split(",")
    col = next(i for i, h in enumerate(header) if h.strip().startswith("Time"))
    row = len(lines) // 2
    cells = lines[row].split(b",")
    cells[col] = value.encode()
    lines[row] = b",".join(cells)
    return b"\n".join(lines)


def transcript(inner: str) -> bytes:
    header = {"format": "thrustmap.transcript", "version": 1, "inner": inner, "created_utc": ""}
    return (json.dumps(header) + "\n").encode()


def nested_json(depth: int = 100_000) -> bytes:
    return b"[" * depth + b"]" * depth


def df_table(cell: str | None = None, row: int = 3, column: str = "voltage_v") -> bytes:
    cols = ["flight", "time_s", "voltage_v", "accel_up_mps2", "force_n", "thrust_cmd_n"]
    lines = [",".join(cols)]
    for i in range(40):
        values = ["f#0", f"{i * 0.1:.1f}", f"{16.0 - i * 0.01:.3f}", "9.81", "14.7", "15.0"]
        if cell is not None and i == row:
            values[cols.index(column)] = cell
        lines.append(",".join(values))
    return ("\n".join(lines) + "\n").encode()


def _unchanged(name: str, content: bytes) -> Callable[[Path], None]:
    def check(folder: Path) -> None:
        assert (folder / name).read_bytes() == content, f"{name} was overwritten"

    return check


def cases() -> list[Case]:
    """Every malformed-input case (each builder reads only our own fixtures)."""
    map_bytes = (LOGS / "sim_map.json").read_bytes()
    paper = (LOGS / "sim_hover_paper.csv").read_bytes()
    run_csv = (SWEEPS / "msp_run.csv").read_bytes()
    run_meta = (SWEEPS / "msp_run.meta.json").read_bytes()
    out: list[Case] = []
    add = out.append
    # 1. hangs
    for header in (
        {"I interval": "99999999"},
        {"P interval": "1/99999999"},
        {"I interval": "65535", "P interval": "1/65535"},
    ):
        add(
            Case(
                "bbl " + ", ".join(f"{k} {v}" for k, v in header.items()),
                ["flightlog", "inspect", "x.bbl"],
                {"x.bbl": bbl_with_header(header)},
                timeout_s=10.0,
            )
        )
    add(
        Case(
            "bbl 20000 fields",
            ["flightlog", "inspect", "x.bbl"],
            {"x.bbl": bbl_many_fields(20000)},
            codes=(2,),
            timeout_s=10.0,
        )
    )
    add(Case("bbl 250 fields", ["flightlog", "inspect", "x.bbl"], {"x.bbl": bbl_many_fields(250)}))
    add(
        Case(
            "dataflash 720 kB, a break per message",
            ["flightlog", "inspect", "x.bin"],
            {"x.bin": dataflash_many_breaks()},
        )
    )
    add(
        Case(
            "ulog pyulog loop",
            ["flightlog", "inspect", "x.ulg"],
            {"x.ulg": ulog_hang()},
            codes=(2,),
            timeout_s=10.0,
        )
    )
    for seed in range(3):
        add(
            Case(
                f"ulog 17 flipped bytes #{seed}",
                ["flightlog", "inspect", "--json", "x.ulg"],
                {"x.ulg": ulog_flipped(seed)},
            )
        )
    # 2. one bad timestamp
    add(
        Case(
            "paper CSV time 3005000",
            ["flightlog", "extract", "x.csv", "-o", "df.csv"],
            {"x.csv": paper_csv_time_typo()},
            timeout_s=10.0,
        )
    )
    add(
        Case(
            "paper CSV time 1e15",
            ["flightlog", "extract", "x.csv", "-o", "df.csv"],
            {"x.csv": paper_csv_time_typo("1e15")},
        )
    )
    # 3. outputs over inputs
    add(
        Case(
            "extract sidecar over the map",
            ["flightlog", "extract", "x.csv", "--map", "mymap.json", "-o", "mymap.csv"],
            {"x.csv": paper, "mymap.json": map_bytes},
            codes=(2,),
            expect="mymap.json",
            after=_unchanged("mymap.json", map_bytes),
        )
    )
    add(
        Case(
            "extract -o df.json",
            ["flightlog", "extract", "x.csv", "-o", "df.json"],
            {"x.csv": paper},
            codes=(2,),
            expect="df.json",
        )
    )
    add(
        Case(
            "extract over its log",
            ["flightlog", "extract", "x.csv", "-o", "x.csv"],
            {"x.csv": paper},
            codes=(2,),
            after=_unchanged("x.csv", paper),
        )
    )
    add(
        Case(
            "fit over its input",
            ["fit", "run.csv", "-o", "run.csv"],
            {"run.csv": run_csv, "run.meta.json": run_meta},
            codes=(2,),
            after=_unchanged("run.csv", run_csv),
        )
    )
    add(
        Case(
            "fit over the input's sidecar",
            ["fit", "run.csv", "-o", "run.meta.json"],
            {"run.csv": run_csv, "run.meta.json": run_meta},
            codes=(2,),
            after=_unchanged("run.meta.json", run_meta),
        )
    )
    add(
        Case(
            "export over the map",
            ["export", "m.json", "--to", "c-header", "-o", "m.json"],
            {"m.json": map_bytes},
            codes=(2,),
            after=_unchanged("m.json", map_bytes),
        )
    )
    df = df_table()
    add(
        Case(
            "gamma fit over the map",
            ["gamma", "fit", "df.csv", "--map", "m.json", "-o", "m.json"],
            {"df.csv": df, "m.json": map_bytes},
            codes=(2,),
            after=_unchanged("m.json", map_bytes),
        )
    )
    add(
        Case(
            "gamma fit over the Df",
            ["gamma", "fit", "df.csv", "--map", "m.json", "-o", "df.csv"],
            {"df.csv": df, "m.json": map_bytes},
            codes=(2,),
            after=_unchanged("df.csv", df),
        )
    )
    # 4. transcripts choose nothing
    for label, inner in (
        ("shadow", "replay:///etc/shadow"),
        ("zero", "replay:///dev/zero"),
        ("self", "replay://t.jsonl"),
        ("record", "record://replay:///dev/zero?file=/tmp/x"),
    ):
        add(
            Case(
                f"transcript inner {label}",
                ["probe", "replay://t.jsonl"],
                {"t.jsonl": transcript(inner)},
            )
        )
    add(Case("replay of /dev/zero", ["probe", "replay:///dev/zero"], codes=(2,)))
    add(
        Case(
            "unknown replay option",
            ["probe", "--kind", "msp", "replay://t.jsonl?bogus=1"],
            {"t.jsonl": transcript("sim://betaflight")},
            codes=(2,),
            expect="bogus",
        )
    )
    # 9. internal errors
    add(Case("fit into a missing folder", ["fit", "run.csv", "-o", "nope/m.json"],
             {"run.csv": run_csv, "run.meta.json": run_meta}, codes=(2,), expect="nope"))  # fmt: skip
    add(Case("gamma fit into a missing folder",
             ["gamma", "fit", "df.csv", "--map", "m.json", "-o", "nope/m.json"],
             {"df.csv": df, "m.json": map_bytes}, codes=(2,), expect="nope"))  # fmt: skip
    add(Case("extract into a missing folder",
             ["flightlog", "extract", "x.csv", "-o", "nope/df.csv"], {"x.csv": paper},
             codes=(2,), expect="nope"))  # fmt: skip
    add(Case("sweep into a missing folder",
             ["sweep", "steps", "--stand", "sim://line-stand", "--throttle", "sim://betaflight", "-y", "-q",
              "-o", "nope/run.csv"], codes=(2,), expect="nope"))  # fmt: skip
    add(Case("nested map", ["predict", "m.json", "--throttle-pct", "50", "--voltage-v", "16"],
             {"m.json": nested_json()}, codes=(2,), expect="m.json"))  # fmt: skip
    add(Case("nested Df sidecar", ["gamma", "fit", "df.csv", "--map", "m.json", "-o", "o.json"],
             {"df.csv": df, "df.json": nested_json(), "m.json": map_bytes}, codes=(2,),
             expect="df.json"))  # fmt: skip
    for label, cell in (
        ("text", "abc"),
        ("400 digits", "9" * 400),
        ("140k characters", "1" * 140_000),
    ):
        add(
            Case(
                f"Df cell {label}",
                ["gamma", "fit", "df.csv", "--map", "m.json", "-o", "o.json"],
                {"df.csv": df_table(cell), "m.json": map_bytes},
                codes=(2,),
                expect="df.csv",
            )
        )
    add(
        Case(
            "map of 400-digit numbers",
            ["predict", "m.json", "--throttle-pct", "50", "--voltage-v", "16"],
            {"m.json": map_bytes.replace(b'"version": 1', b'"version": 1' + b"0" * 400, 1)},
            codes=(2,),
        )
    )
    add(Case("non-UTF-8 calibration",
             ["sweep", "steps", "--stand", "sim://tyto-1585", "--throttle", "sim://betaflight", "-y", "-q",
              "--tyto-calibration", "cal.json", "-o", "run.csv"],
             {"cal.json": b'{"serial": "\xff\xfe"}'}, codes=(2,), expect="cal.json"))  # fmt: skip
    add(Case("compare --folds 0", ["compare", "run.csv", "--validate", "kfold", "--folds", "0"],
             {"run.csv": run_csv, "run.meta.json": run_meta}, codes=(2,), expect="folds"))  # fmt: skip
    bb_csv = (LOGS / "bb_hover_sim.01.csv").read_bytes()
    add(Case("blackbox CSV with a quote", ["flightlog", "inspect", "x.csv"],
             {"x.csv": bb_csv[:5000] + b'"' + bb_csv[5000:]}))  # fmt: skip
    add(Case("blackbox CSV ragged", ["flightlog", "inspect", "x.csv"],
             {"x.csv": bb_csv.replace(b"\n", b",1,2,3\n", 30)}))  # fmt: skip
    one_row = b"\n".join(paper.split(b"\n")[:2]) + b"\n"
    add(Case("one-sample log", ["flightlog", "extract", "x.csv", "-o", "df.csv"],
             {"x.csv": one_row}))  # fmt: skip
    return out


# -- bounded runner -------------------------------------------------------------------------------


def run_cases(
    selected: list[Case], workdir: Path, *, timeout_s: float = 30.0, memory_bytes: int = 1 << 30
) -> list[CliResult]:
    """Run every case through thrustmap.cli.main in a forked child, one folder each."""
    warm()
    workdir.mkdir(parents=True, exist_ok=True)
    results: list[CliResult] = []
    for k, case in enumerate(selected):
        folder = workdir / f"case{k}"
        folder.mkdir()
        for name, content in case.files.items():
            (folder / name).write_bytes(content)
        results.append(_run_one(case, folder, min(timeout_s, case.timeout_s), memory_bytes))
    return results


def warm() -> None:
    """Import the commands once in the parent, so each forked child starts at once."""
    import importlib

    from thrustmap.cli import COMMANDS

    # (tests/conftest.py sets ARROW_DEFAULT_MEMORY_POOL=system, for the children's RLIMIT_AS)
    for target in set(COMMANDS.values()):
        importlib.import_module("thrustmap.cli." + target.split(":")[0])
    for name in ("pandas", "scipy.optimize", "pyulog", "pymavlink.mavutil"):
        with contextlib.suppress(ImportError):
            importlib.import_module(name)


def _run_one(case: Case, folder: Path, timeout_s: float, memory_bytes: int) -> CliResult:
    read_fd, write_fd = os.pipe()
    t0 = time.monotonic()
    pid = os.fork()
    if pid == 0:  # child
        os.close(read_fd)
        try:
            _child(case, folder, memory_bytes, write_fd)
        finally:
            os._exit(0)
    os.close(write_fd)
    deadline = t0 + timeout_s
    blob = b""
    with os.fdopen(read_fd, "rb") as pipe:
        os.set_blocking(pipe.fileno(), False)
        while time.monotonic() < deadline:
            try:
                chunk = pipe.read()
            except BlockingIOError:
                chunk = None
            if chunk:
                blob += chunk
            done, _ = os.waitpid(pid, os.WNOHANG)
            if done:
                rest = pipe.read()
                blob += rest or b""
                break
            time.sleep(0.02)
        else:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            return CliResult(case.name, None, "", "", timeout_s, "timed out")
    seconds = time.monotonic() - t0
    if not blob:
        return CliResult(case.name, None, "", "", seconds, "child died (memory limit?)")
    code, stdout, stderr = pickle.loads(blob)
    return CliResult(case.name, code, stdout, stderr, seconds)


def _child(case: Case, folder: Path, memory_bytes: int, write_fd: int) -> None:
    import io
    import logging

    with open("/proc/self/statm") as f:
        vm = int(f.read().split()[0]) * resource.getpagesize()
    resource.setrlimit(resource.RLIMIT_AS, (vm + memory_bytes, vm + memory_bytes))
    os.chdir(folder)
    for h in list(logging.getLogger().handlers):  # pytest's capture handlers
        logging.getLogger().removeHandler(h)
    out, err = io.StringIO(), io.StringIO()
    sys.stdout, sys.stderr = out, err
    code = 0
    try:
        from thrustmap.cli import main

        main(list(case.argv))
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    except BaseException as exc:  # noqa: BLE001 - reported as a failure
        code = 99
        err.write(f"uncaught {type(exc).__name__}: {exc}\n")
    with os.fdopen(write_fd, "wb") as pipe:
        pipe.write(pickle.dumps((code, out.getvalue(), err.getvalue())))


def problems(case: Case, result: CliResult, folder: Path | None = None) -> list[str]:
    """What is wrong with a case's result (empty when it is acceptable)."""
    bad: list[str] = []
    if result.code is None:
        return [f"{case.name}: {result.note} after {result.seconds:.1f} s"]
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    if result.code not in case.codes:
        bad.append(f"{case.name}: exit {result.code} (expected {case.codes}): {lines[-3:]}")
    if result.code == 2 and len(lines) != 1:
        bad.append(f"{case.name}: exit 2 with {len(lines)} stderr lines: {lines[:4]}")
    if any("internal error" in ln or "Traceback" in ln for ln in lines):
        bad.append(f"{case.name}: internal error: {lines[-2:]}")
    if result.code == 2 and case.expect and lines and case.expect not in lines[0]:
        bad.append(f"{case.name}: error does not name {case.expect!r}: {lines[0]}")
    if result.code == 0 and "--json" in case.argv:
        try:
            json.loads(result.stdout)
        except ValueError:
            bad.append(f"{case.name}: --json output is not JSON: {result.stdout[:120]!r}")
    if case.after is not None and folder is not None:
        try:
            case.after(folder)
        except AssertionError as exc:
            bad.append(f"{case.name}: {exc}")
    return bad
