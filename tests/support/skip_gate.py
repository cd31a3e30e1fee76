"""No silent skips: every skipped test, by reason, against tests/skip-allowlist.toml.

Test support only. As a pytest plugin (tests/conftest.py loads its hooks; elsewhere
``-p support.skip_gate``), ``--skip-report FILE`` writes every skipped test and its reason as
JSON. As a command it prints the table of skips by reason and exits 1 when a reason is not on
the allow-list (each entry there says why CI cannot run the test and where the evidence lives
instead); .ci/run ends with it:

    python tests/support/skip_gate.py REPORT.json [--allowlist tests/skip-allowlist.toml]
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

if sys.version_info >= (3, 11):
    import tomllib
else:  # the test extra installs tomli on 3.10
    import tomli as tomllib

ALLOWLIST = Path(__file__).resolve().parents[1] / "skip-allowlist.toml"


@dataclass(frozen=True)
class Allowed:
    pattern: str  # a regular expression searched in the skip's reason
    why: str  # why CI cannot run the test
    evidence: str  # where the evidence lives instead


def load_allowlist(path: Path = ALLOWLIST) -> list[Allowed]:
    data = tomllib.loads(path.read_text(encoding="utf-8"))
    out = []
    for i, e in enumerate(data.get("skip", [])):
        missing = [k for k in ("reason", "why", "evidence") if not str(e.get(k, "")).strip()]
        if missing:
            raise ValueError(f"{path}: [[skip]] entry {i + 1} lacks {', '.join(missing)}")
        re.compile(e["reason"])
        out.append(Allowed(e["reason"], e["why"], e["evidence"]))
    return out


def allowed_by(reason: str, allowlist: list[Allowed]) -> Allowed | None:
    return next((a for a in allowlist if re.search(a.pattern, reason)), None)


def table(skips: list[dict[str, str]], allowlist: list[Allowed]) -> tuple[list[str], list[str]]:
    """The lines of the table of skips by reason, and the node ids of the unlisted ones."""
    by_reason: dict[str, list[str]] = {}
    for s in skips:
        by_reason.setdefault(s["reason"], []).append(s["nodeid"])
    lines = [f"{'tests':>5s}  {'allowed':7s}  reason"]
    unlisted: list[str] = []
    for reason, ids in sorted(by_reason.items(), key=lambda kv: (-len(kv[1]), kv[0])):
        entry = allowed_by(reason, allowlist)
        lines.append(f"{len(ids):5d}  {'yes' if entry else 'NO':7s}  {reason}")
        if entry:
            lines.append(f"{'':16s}evidence instead: {entry.evidence}")
        else:
            unlisted += ids
    return lines, unlisted


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="skipped tests by reason, against the allow-list")
    ap.add_argument("report", type=Path, help="the JSON written by pytest --skip-report")
    ap.add_argument("--allowlist", type=Path, default=ALLOWLIST)
    a = ap.parse_args(argv)
    text = a.report.read_text(encoding="utf-8") if a.report.is_file() else ""
    if not text.strip():
        print(f"FAIL: no skip report in {a.report} (pytest stopped before its end?)")
        return 1
    skips = json.loads(text)
    lines, unlisted = table(skips, load_allowlist(a.allowlist))
    print(f"== skipped tests by reason ({len(skips)} skipped; allow-list {a.allowlist.name})")
    print("\n".join(lines) if skips else "none")
    if unlisted:
        print(f"FAIL: {len(unlisted)} skip(s) with a reason not on {a.allowlist}:")
        print("\n".join(f"  {n}" for n in unlisted))
        return 1
    return 0


# -- the pytest plugin ---------------------------------------------------------------------------

_SKIPS: list[dict[str, str]] = []


def pytest_addoption(parser: Any) -> None:
    parser.addoption(
        "--skip-report",
        metavar="FILE",
        help="write every skipped test and its reason to FILE (JSON; tests/support/skip_gate.py)",
    )


def pytest_runtest_logreport(report: Any) -> None:
    if report.skipped and not hasattr(report, "wasxfail"):
        longrepr = report.longrepr
        reason = longrepr[2] if isinstance(longrepr, tuple) else str(longrepr)
        reason = reason.removeprefix("Skipped: ")
        _SKIPS.append({"nodeid": report.nodeid, "reason": reason})


def pytest_collectreport(report: Any) -> None:
    pytest_runtest_logreport(report)  # a module skipped whole (importorskip at module level)


def pytest_sessionfinish(session: Any) -> None:
    path = session.config.getoption("--skip-report")
    if path:
        Path(path).write_text(json.dumps(_SKIPS, indent=1), encoding="utf-8")


if __name__ == "__main__":
    sys.exit(main())
