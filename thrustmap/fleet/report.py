"""The fleet HTML report: groups, logs per group, γ(B) per group with its band, refused logs
by reason. Self-contained (inline SVG, the main report's styles), no network, no script."""

from __future__ import annotations

import html
import math
import re
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from thrustmap.core.files import atomic_write_text
from thrustmap.fitting.mapfile import gamma_text
from thrustmap.fleet.groups import Group
from thrustmap.fleet.task import Outcome
from thrustmap.report.html import CSS

MAX_LOGS_LISTED = 50  # per group and per reason; the rest are counted


def _e(x: Any) -> str:
    return html.escape(str(x))


def _table(head: Sequence[str], rows: Iterable[Sequence[str]], left: Sequence[int] = ()) -> str:
    cls = ' class="l"'
    h = "".join(f"<th{cls if i in left else ''}>{_e(c)}</th>" for i, c in enumerate(head))
    body = "".join("<tr>" + "".join(r) + "</tr>" for r in rows)
    return f'<div class="tw"><table><tr>{h}</tr>{body}</table></div>'


def _td(text: Any, left: bool = False, value: float | None = None) -> str:
    cls = ' class="l"' if left else ""
    data = f' data-value="{value!r}"' if value is not None and math.isfinite(value) else ""
    return f"<td{cls}{data}>{_e(text)}</td>"


def gamma_formula(coefficients: Sequence[float]) -> str:
    """γ(B) as text: ``1.6091 − 0.020368·B`` (``mapfile.gamma_text``)."""
    return gamma_text(coefficients)


def _svg(g: Group, width: int = 420, height: int = 220) -> str:
    """γ(B) over the group's flown voltage with its 95 % band."""
    if g.fit is None or g.voltage_v is None:
        return ""
    lo, hi = g.voltage_v
    n = 40
    bs = [lo + (hi - lo) * i / (n - 1) for i in range(n)]
    coef = g.fit.correction.coefficients
    ys = [sum(c * b**k for k, c in enumerate(coef)) for b in bs]
    blo, bhi = g.band if g.band is not None else (0.0, 0.0)
    ymin, ymax = min(ys) + blo, max(ys) + bhi
    pad = 0.05 * (ymax - ymin or 0.01)
    ymin, ymax = ymin - pad, ymax + pad
    ml, mr, mt, mb = 52, 26, 10, 34

    def x(b: float) -> float:
        return ml + (b - lo) / ((hi - lo) or 1.0) * (width - ml - mr)

    def y(v: float) -> float:
        return mt + (ymax - v) / ((ymax - ymin) or 1.0) * (height - mt - mb)

    line = " ".join(f"{x(b):.1f},{y(v):.1f}" for b, v in zip(bs, ys, strict=True))
    upper = [f"{x(b):.1f},{y(v + bhi):.1f}" for b, v in zip(bs, ys, strict=True)]
    lower = [f"{x(b):.1f},{y(v + blo):.1f}" for b, v in zip(bs, ys, strict=True)]
    band = " ".join(upper + lower[::-1])
    ticks = []
    for i in range(3):
        b = lo + (hi - lo) * i / 2
        ticks.append(
            f'<text x="{x(b):.1f}" y="{height - 18}" text-anchor="middle" font-size="11">'
            f"{b:.2f}</text>"
        )
        v = ymin + (ymax - ymin) * i / 2
        ticks.append(
            f'<text x="{ml - 4}" y="{y(v) + 4:.1f}" text-anchor="end" font-size="11">{v:.3f}</text>'
        )
    return (
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
        f'role="img" aria-label="gamma of B for {_e(g.label)}">'
        f'<rect x="{ml}" y="{mt}" width="{width - ml - mr}" height="{height - mt - mb}" '
        'fill="#fbfcfe" stroke="#d6dae2"/>'
        f'<polygon points="{band}" fill="#93c5fd" fill-opacity="0.45" stroke="none"/>'
        f'<polyline points="{line}" fill="none" stroke="#1d4ed8" stroke-width="2"/>'
        + "".join(ticks)
        + f'<text x="{(width + ml) / 2:.0f}" y="{height - 3}" text-anchor="middle" '
        'font-size="12">battery voltage B (V)</text>'
        f'<text x="12" y="{mt + 12}" font-size="12">γ</text></svg>'
    )


def _reason_key(o: Outcome) -> str:
    """A refusal's reason without the file name and the bytes that differ from file to file."""
    text = o.reason
    if text.startswith(o.path + ":"):
        text = text[len(o.path) + 1 :].strip()
    text = re.sub(r"\(first bytes b?['\"].*?['\"]\)", "(first bytes ...)", text)
    text = re.sub(r"\b\d+(\.\d+)?\b", "N", text)
    return text[:300]


def render(outcomes: list[Outcome], groups: list[Group], title: str) -> str:
    counts: dict[str, int] = {}
    for o in outcomes:
        counts[o.status] = counts.get(o.status, 0) + 1
    parts = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
        f"<title>{_e(title)}</title><style>{CSS}</style></head><body>",
        f"<header><h1>{_e(title)}</h1><p>{len(outcomes)} logs: {counts.get('ok', 0)} "
        f"extracted, {counts.get('empty', 0)} with no steady flight, "
        f"{counts.get('refused', 0)} refused; {len(groups)} airframe groups, "
        f"{sum(g.status == 'fitted' for g in groups)} fitted</p></header>",
        "<nav><a href='#groups'>Groups</a><a href='#gamma'>γ(B) per group</a>"
        "<a href='#logs'>Logs per group</a><a href='#refused'>Refused logs</a></nav><main>",
    ]
    rows = []
    for g in groups:
        a = g.airframe
        v = "" if g.voltage_v is None else f"{g.voltage_v[0]:.2f}..{g.voltage_v[1]:.2f}"
        gam = gamma_formula(g.fit.correction.coefficients) if g.fit is not None else ""
        rows.append(
            [
                _td(g.label, left=True),
                _td(a.get("format", ""), left=True),
                _td(a.get("motor_channels", ""), left=True),
                _td(len(g.logs), value=len(g.logs)),
                _td(g.samples, value=g.samples),
                _td(v),
                _td(g.status, left=True),
                _td(gam or g.reason, left=True),
            ]
        )
    parts.append("<section id='groups'><h2>Airframe groups</h2>")
    parts.append(
        "<p class='small'>A group is one autopilot, frame and motor outputs, the parameters "
        "that shape the thrust curve (motor output range, spin and expo, thrust model), and "
        "the mass when given.</p>"
    )
    parts.append(
        _table(
            ["group", "format", "motors", "logs", "Df samples", "voltage V", "status", "γ(B)"],
            rows,
            left=(0, 1, 2, 6, 7),
        )
    )
    parts.append("</section><section id='gamma'><h2>γ(B) per group</h2>")
    if not any(g.fit is not None for g in groups):
        why = (
            "".join(f"<li>{_e(g.label)}: {_e(g.status)}: {_e(g.reason)}</li>" for g in groups)
            if groups
            else "<li>no log of the fleet gave a Df (see the refused logs)</li>"
        )
        parts.append(f"<p>No group was fitted, so no γ(B) and no corrected map:</p><ul>{why}</ul>")
    for g in groups:
        if g.fit is None:
            continue
        f = g.fit
        band = (
            ""
            if g.band is None
            else f"; 95 % of per-sample γ within {g.band[0]:+.4f} / {g.band[1]:+.4f} of it"
        )
        parts.append(
            f"<h3>{_e(g.label)}</h3><p>γ(B) = {_e(gamma_formula(f.correction.coefficients))} "
            f"(degree {f.degree}, {f.loss}, {f.samples} samples, {_e(f.validation)}; held-out "
            f"error {f.heldout.get(f.degree, float('nan')):.4g}{_e(band)})</p>"
        )
        parts.append(
            "<div class='pair'>"
            + _svg(g)
            + _table(
                ["coefficient", "value"],
                [
                    [_td(f"B^{k}", left=True), _td(f"{c:.8g}", value=c)]
                    for k, c in enumerate(f.correction.coefficients)
                ],
            )
            + "</div>"
        )
        for w in g.warnings:
            parts.append(f"<p class='note'>{_e(w)}</p>")
    parts.append("</section><section id='logs'><h2>Logs per group</h2>")
    for g in groups:
        shown = g.logs[:MAX_LOGS_LISTED]
        more = len(g.logs) - len(shown)
        parts.append(
            f"<h3>{_e(g.label)}: {len(g.logs)} logs</h3><p class='small'>"
            + "<br>".join(f"<code>{_e(p)}</code>" for p in shown)
            + (f"<br>... and {more} more" if more > 0 else "")
            + "</p>"
        )
    empty = [o for o in outcomes if o.status == "empty"]
    if empty:
        parts.append(f"<h3>No steady flight: {len(empty)} logs</h3>")
        parts.append(
            _table(
                ["log", "why"],
                [[_td(o.path, left=True), _td(o.reason, left=True)] for o in empty[:200]],
            )
        )
    refused = [o for o in outcomes if o.status == "refused"]
    by_reason: dict[str, list[Outcome]] = {}
    for o in refused:
        by_reason.setdefault(_reason_key(o), []).append(o)
    parts.append(f"</section><section id='refused'><h2>Refused logs: {len(refused)}</h2>")
    rrows = []
    for reason, logs in sorted(by_reason.items(), key=lambda kv: (-len(kv[1]), kv[0])):
        names = ", ".join(Path(o.path).name for o in logs[:MAX_LOGS_LISTED])
        if len(logs) > MAX_LOGS_LISTED:
            names += f", ... and {len(logs) - MAX_LOGS_LISTED} more"
        rrows.append([_td(len(logs), value=len(logs)), _td(reason, left=True),
                      _td(names, left=True)])  # fmt: skip
    parts.append(
        _table(["logs", "reason", "files"], rrows, left=(1, 2)) if rrows else "<p>None.</p>"
    )
    parts.append("</section></main></body></html>")
    return "".join(parts)


def write_fleet_report(outcomes: list[Outcome], groups: list[Group], path: Path) -> int:
    text = render(outcomes, groups, "thrustmap fleet report")
    atomic_write_text(path, text)
    return len(text.encode())
