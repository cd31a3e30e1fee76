"""The self-contained HTML report: figures as inline PNG, numbers as tables, one small script.

No network: styles and the interactive 3D view (a canvas, ~60 lines of inline JS) are in the
file; every figure is also a static image, so the report reads without JavaScript. Every number
in a table carries its full value in ``data-value`` so tools and tests can read it exactly.
"""

from __future__ import annotations

import base64
import html
import json
import math
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from thrustmap.fitting.extrapolation import (
    COMMAND,
    EVIDENCE,
    EVIDENCE_LIMIT_THRUST_RATIO,
    EVIDENCE_LIMIT_VOLTAGE_LOG,
    EXTRAPOLATION_GROWTH,
)
from thrustmap.fitting.fit.validation import Row
from thrustmap.report import figures
from thrustmap.report.data import ReportData, source_files

SECTIONS = (
    ("provenance", "Provenance"),
    ("sweeps", "Raw sweeps and steady-state selection"),
    ("surface", "Fitted map"),
    ("residuals", "Residuals"),
    ("validation", "Validation of every model"),
    ("coverage", "Coverage and uncertainty"),
    ("gamma", "Flight correction γ(B)"),
    ("exports", "Firmware exports"),
)

#: the nav bar's short labels: one line at 1280 px (the section headings keep the long titles)
NAV = {
    "sweeps": "Sweeps",
    "surface": "Map",
    "validation": "Validation",
    "coverage": "Coverage",
    "gamma": "γ(B)",
    "exports": "Exports",
}

CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:0;color:#1d2330;
background:#fff;line-height:1.45}
header{background:#1d2330;color:#fff;padding:18px 28px}header h1{margin:0;font-size:22px}
header p{margin:4px 0 0;opacity:.8}nav{padding:8px 28px;background:#eef1f6;font-size:14px;white-space:nowrap;overflow-x:auto}
nav a{margin-right:14px;color:#1d4ed8;text-decoration:none}
main{padding:0 28px 40px;max-width:1400px}section{border-bottom:1px solid #e3e6ec;padding:10px 0}
h2{font-size:18px;margin:18px 0 8px}h3{font-size:15px;margin:14px 0 6px}
table{border-collapse:collapse;font-size:13px;margin:6px 0 10px}
th,td{border:1px solid #d6dae2;padding:3px 7px;text-align:right}
th{background:#f3f5f9}td.l,th.l{text-align:left}code{font-size:11px;word-break:break-all}
img.fig{max-width:100%;height:auto;border:1px solid #eee}
.note{color:#8a5300;background:#fff7e6;padding:4px 8px;border-left:3px solid #f0a020}
.pair{display:flex;flex-wrap:wrap;gap:14px;align-items:flex-start}
.tw{overflow-x:auto}table.validation td{white-space:nowrap}th[colspan]{text-align:center}canvas{border:1px solid #d6dae2;cursor:grab;background:#fbfcfe}.small{font-size:12px;color:#555}
"""

# Drag to rotate, wheel to zoom: a wireframe of the surface and the points, painter-sorted.
JS = """
(function(){var d=JSON.parse(document.getElementById('surface-data').textContent);
var c=document.getElementById('surface3d');if(!c||!c.getContext)return;var g=c.getContext('2d');
var az=-2.3,el=0.45,zoom=1,drag=null;c.style.display='block';
function nrm(v,lo,hi){return hi>lo?(v-lo)/(hi-lo)-0.5:0}
function P(t,b,z){var x=nrm(t,d.t[0],d.t[1]),y=nrm(b,d.b[0],d.b[1]),h=nrm(z,d.z[0],d.z[1]);
var ca=Math.cos(az),sa=Math.sin(az),ce=Math.cos(el),se=Math.sin(el);
var X=x*ca-y*sa,Y=x*sa+y*ca,s=Math.min(c.width,c.height)*0.5*zoom;
return [c.width/2+X*s,c.height/2-(h*ce-Y*se)*s,Y*ce+h*se]}
function col(z){var f=Math.max(0,Math.min(1,(z-d.z[0])/(d.z[1]-d.z[0]||1)));
return 'rgb('+Math.round(68+f*185)+','+Math.round(1+f*230)+','+Math.round(84+f*(-50))+')'}
function draw(){g.clearRect(0,0,c.width,c.height);var q=[],G=d.grid,n=G.length,m=G[0].length,i,j;
for(i=0;i<n-1;i++)for(j=0;j<m-1;j++){var a=G[i][j],b=G[i+1][j],e=G[i+1][j+1],f=G[i][j+1];
var ps=[P(a[0],a[1],a[2]),P(b[0],b[1],b[2]),P(e[0],e[1],e[2]),P(f[0],f[1],f[2])];
q.push({k:0,p:ps,z:(ps[0][2]+ps[2][2])/2,c:col((a[2]+e[2])/2)})}
for(i=0;i<d.pts.length;i++){var p=d.pts[i],r=P(p[0],p[1],p[2]);q.push({k:1,p:r,z:r[2]+1e-3})}
q.sort(function(u,v){return v.z-u.z});
for(i=0;i<q.length;i++){var o=q[i];if(o.k===0){g.beginPath();g.moveTo(o.p[0][0],o.p[0][1]);
for(j=1;j<4;j++)g.lineTo(o.p[j][0],o.p[j][1]);g.closePath();g.fillStyle=o.c;g.globalAlpha=.75;
g.fill();g.globalAlpha=1;g.strokeStyle='rgba(40,40,60,.25)';g.stroke()}else{g.fillStyle='#111';
g.fillRect(o.p[0]-1.5,o.p[1]-1.5,3,3)}}
var lo=[d.t[0],d.b[0],d.z[0]],hi=[d.t[1],d.b[1],d.z[1]],names=['T (N)','B (V)','Th (%)'];
function Pv(v){return P(v[0],v[1],v[2])}
function fmt(v){var a=Math.abs(v);return a>=100?v.toFixed(0):a>=10?v.toFixed(1):v.toFixed(2)}
function lab(x,y,s,right){var w=g.measureText(s).width;if(right)x-=w;
g.fillStyle='rgba(255,255,255,.85)';g.fillRect(x-2,y-11,w+4,14);g.fillStyle='#333';g.fillText(s,x,y)}
g.strokeStyle='#333';g.font='12px sans-serif';
var back=lo.slice(),best=-1e9;[[lo[0],lo[1]],[hi[0],lo[1]],[lo[0],hi[1]],[hi[0],hi[1]]].forEach(
function(q){var z=-P(q[0],q[1],lo[2])[2];if(z>best){best=z;back=[q[0],q[1],lo[2]]}});
for(i=0;i<3;i++){var base=i===2?back:lo,O=Pv(base),e1=base.slice();e1[i]=hi[i];var A=Pv(e1);
g.beginPath();g.moveTo(O[0],O[1]);g.lineTo(A[0],A[1]);g.stroke();
for(var k=(i===2?1:0);k<=2;k++){var pt=base.slice();pt[i]=lo[i]+(hi[i]-lo[i])*k/2;var Q=Pv(pt);
g.beginPath();g.arc(Q[0],Q[1],2,0,6.3);g.fillStyle='#333';g.fill();
if(i===0)lab(Q[0]-8,Q[1]+14,fmt(pt[i]),true);else if(i===1)lab(Q[0]+6,Q[1]+14,fmt(pt[i]));
else lab(Q[0]-6,Q[1]+4,fmt(pt[i]),true)}
var e2=base.slice();e2[i]=hi[i]+(hi[i]-lo[i])*0.22;var L=Pv(e2);lab(L[0]+4,L[1],names[i],i===2)}}
c.onmousedown=function(e){drag=[e.clientX,e.clientY]};window.onmouseup=function(){drag=null};
window.onmousemove=function(e){if(!drag)return;az+=(e.clientX-drag[0])*0.01;
el=Math.max(-1.5,Math.min(1.5,el+(e.clientY-drag[1])*0.01));drag=[e.clientX,e.clientY];draw()};
c.onwheel=function(e){e.preventDefault();zoom*=e.deltaY<0?1.1:0.9;draw()};draw()})();
"""


def _e(x: Any) -> str:
    return html.escape(str(x), quote=True)


def _num(value: float | int | None, fmt: str = ".3f", key: str = "") -> str:
    """A table cell showing ``value`` formatted, carrying the exact value in data-value."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return f'<td data-key="{_e(key)}" data-value="null">–</td>'
    return f'<td data-key="{_e(key)}" data-value="{value!r}">{format(value, fmt)}</td>'


def _table(head: Sequence[str], rows: Iterable[Sequence[str]], cls: str = "") -> str:
    h = "".join(
        f'<th class="l">{_e(x)}</th>' if i == 0 else f"<th>{_e(x)}</th>" for i, x in enumerate(head)
    )
    body = "".join("<tr>" + "".join(r) + "</tr>" for r in rows)
    return f'<div class="tw"><table class="{cls}"><tr>{h}</tr>{body}</table></div>'


def _td(text: Any, left: bool = True) -> str:
    return f'<td class="{"l" if left else ""}">{_e(text)}</td>'


def _img(name: str, rd: ReportData, alt: str) -> str:
    png = figures.render(name, rd, "png", dpi=96)
    b64 = base64.b64encode(png).decode("ascii")
    return f'<img class="fig" id="fig-{name}" alt="{_e(alt)}" src="data:image/png;base64,{b64}">'


def _provenance(rd: ReportData) -> str:
    t = rd.tmap
    sc = t.throttle_scale
    rows = [
        ("model", f"{t.model}: {t.model_def.formula}"),
        ("loss", t.loss),
        ("strategy / rotors on ESC", f"{t.strategy} / {t.rotors_on_esc or 'not recorded'}"),
        ("throttle scale", sc.describe()),
        (
            "validity box",
            f"T {t.validity.thrust_n.lo:.3f}..{t.validity.thrust_n.hi:.3f} N, "
            f"B {t.validity.voltage_v.lo:.2f}..{t.validity.voltage_v.hi:.2f} V",
        ),
        ("map written by", f"thrustmap {t.tool_version} at {t.created_utc}"),
        ("report written by", f"thrustmap {rd.tool_version}"),
    ]
    out = _table(("field", "value"), ([_td(k), _td(v)] for k, v in rows))
    files = source_files(rd)
    cols = (
        "role",
        "path",
        "sha256",
        "format",
        "samples",
        "stand",
        "fc",
        "motor_protocol",
        "battery_cells",
        "rotors_on_esc",
        "throttle_scale",
    )
    out += "<h3>Files</h3>" + _table(
        (
            "role",
            "file",
            "sha256",
            "format",
            "samples",
            "stand",
            "FC / firmware",
            "motor protocol",
            "battery cells",
            "rotors on ESC",
            "throttle scale",
        ),
        (
            [
                _td(f.get(c, ""))
                if c != "sha256"
                else f'<td class="l"><code>{_e(f.get(c, ""))}</code></td>'
                for c in cols
            ]
            for f in files
        ),
    )
    return out


def _sweeps(rd: ReportData) -> str:
    rows = []
    for p in rd.points.points:
        r = p.report
        rows.append(
            [
                _td(r.get("file")),
                _num(r.get("samples"), "d"),
                _num(len(p), "d"),
                _num(r.get("plateaus"), "d"),
                _num(r.get("settling_samples_dropped"), "d"),
                _num(r.get("ramp_samples_kept"), "d"),
                _num(r.get("ramp_pair_points"), "d"),
                _num(r.get("transient_samples_dropped"), "d"),
                _num(r.get("dropped_by_range"), "d"),
            ]
        )
    method = (
        "every sample (the paper's method)"
        if rd.selection.all_samples
        else "steady state: settled plateau means and quasi-static / paired ramp samples"
    )
    return (
        f"<p>Selection: {_e(method)}.</p>"
        + _img("sweep", rd, "raw sweeps over time")
        + _table(
            (
                "file",
                "samples",
                "points",
                "plateaus",
                "settling dropped",
                "ramp kept",
                "ramp-pair points",
                "transient dropped",
                "dropped by range",
            ),
            rows,
        )
    )


def _surface_data(rd: ReportData) -> str:
    step = max(1, rd.grid_t.shape[0] // 20)
    gt, gb, gz = (a[::step, ::step] for a in (rd.grid_t, rd.grid_b, rd.grid_th))
    grid = [
        [
            [round(float(gt[i, j]), 4), round(float(gb[i, j]), 3), round(float(gz[i, j]), 3)]
            for j in range(gt.shape[1])
        ]
        for i in range(gt.shape[0])
    ]
    p = rd.points
    idx = np.arange(len(p))
    if len(idx) > 1500:
        idx = np.linspace(0, len(p) - 1, 1500).astype(int)
    pts = [
        [
            round(float(p.thrust_n[i]), 4),
            round(float(p.voltage_v[i]), 3),
            round(float(p.throttle_pct[i]), 3),
        ]
        for i in idx
    ]
    zs = np.concatenate([gz.ravel(), p.throttle_pct])
    v = rd.tmap.validity
    doc = {
        "t": [v.thrust_n.lo, v.thrust_n.hi],
        "b": [v.voltage_v.lo, v.voltage_v.hi],
        "z": [float(np.nanmin(zs)), float(np.nanmax(zs))],
        "grid": grid,
        "pts": pts,
    }
    return json.dumps(doc).replace("</", "<\\/")


def _surface(rd: ReportData) -> str:
    c = rd.tmap.coefficients
    # a coefficient held at its bound (k0 = 0) comes out of the solver as rounding noise
    # (3.6e-14): shown as the 0 it is
    floor = 1e-9 * max((abs(float(x)) for x in c), default=0.0)
    coef = _table(
        ("term", "coefficient"),
        (
            [_td(n), _num(0.0 if abs(float(x)) <= floor else x, ".6g", f"coef:{n}")]
            for n, x in zip(rd.tmap.model_def.term_names, c, strict=True)
        ),
    )
    return (
        '<div class="pair"><div>'
        + _img("surface", rd, "fitted surface with the data")
        + '</div><div><canvas id="surface3d" width="520" height="420" style="display:none">'
        '</canvas><p class="small">Interactive: drag to rotate, wheel to zoom (needs '
        "JavaScript; the picture at left is the same surface).</p></div></div>"
        f'<script type="application/json" id="surface-data">{_surface_data(rd)}</script>'
        f"<h3>Coefficients ({_e(rd.tmap.model_def.formula)})</h3>{coef}"
        "<h3>Throttle against thrust at several voltages</h3>" + _img("slices", rd, "slices")
    )


def _stats_cells(prefix: str, s: dict[str, Any]) -> list[str]:
    return [
        _num(s.get(k), "d" if k == "n" else ".3f", f"{prefix}:{k}")
        for k in ("n", "mean_pct", "std_pct", "p95_pct", "max_pct")
    ]


def _residuals(rd: ReportData) -> str:
    s = rd.tmap.metrics.get("in_sample", {})
    r = rd.residual_pct
    now = {
        "n": len(r),
        "mean_pct": float(np.mean(np.abs(r))),
        "std_pct": float(np.std(np.abs(r))),
        "p95_pct": float(np.percentile(np.abs(r), 95)),
        "max_pct": float(np.max(np.abs(r))),
    }
    rows = [
        [_td("as recorded in the map")] + _stats_cells("map-in-sample", s),
        [_td("recomputed on these files")] + _stats_cells("report-in-sample", now),
    ]
    return _img("residuals", rd, "residuals") + _table(
        ("|residual| (% throttle)", "n", "mean", "std", "p95", "max"), rows
    )


def _coverage_cells(r: Row, k: str) -> list[str]:
    """Two cells: the share of held-out points the fold's 95 % interval held, inside / outside
    the supported region, and the interval's median half-width there."""
    ci, co = r.coverage_inside, r.coverage_outside
    if ci is None or co is None:
        return [_td("-"), _td("-")]
    held = " / ".join(f"{c.coverage_pct:.1f}" if c.n else "-" for c in (ci, co))
    width = " / ".join(f"{c.median_half_width_pct:.2f}" if c.n else "-" for c in (ci, co))
    return [
        f'<td data-key="{k}:coverage_pct" data-value="{ci.coverage_pct!r}" '
        f'data-outside="{co.coverage_pct!r}">{held}</td>',
        _td(width),
    ]


def _validation(rd: ReportData) -> str:
    if not rd.validation:
        return "<p>No validation was computed.</p>"
    modes = list(rd.validation)
    by_model: dict[str, dict[str, Row]] = {}
    for m, rows in rd.validation.items():
        for row in rows:
            by_model.setdefault(row.model, {})[m] = row
    tables = ""
    # One table per validation mode, so the table reads on a laptop screen and in print
    # (all modes side by side were ~1500 px wide, the k-fold columns behind a scrollbar).
    for m in modes:
        head = '<th class="l">model</th><th>n</th><th>mean ± std %</th><th>p95 %</th><th>max %</th>'
        if m != "in-sample":
            head += "<th>inside supported region n</th><th>inside mean %</th>"
            head += "<th>outside it n</th><th>outside mean %</th>"
            head += "<th>95 % interval held in / out %</th><th>median ± %</th>"
        body = []
        for model, per in by_model.items():
            if m not in per:
                continue
            r = per[m]
            k = f"{m}:{model}"
            s = r.all  # the headline counts every held-out point
            cells = [_td(model + (" (this map)" if model == rd.tmap.model else ""))]
            cells += [
                _num(s.n, "d", f"{k}:n"),
                f'<td data-key="{k}:mean_pct" data-value="{s.mean_pct!r}" '
                f'data-std="{s.std_pct!r}">{s.mean_pct:.3f} ± {s.std_pct:.3f}</td>',
                _num(s.p95_pct, ".3f", f"{k}:p95_pct"),
                _num(s.max_pct, ".3f", f"{k}:max_pct"),
            ]
            if m != "in-sample":
                cells += [
                    _num(r.inside.n, "d", f"{k}:inside_n"),
                    _num(r.inside.mean_pct, ".3f", f"{k}:inside_mean_pct"),
                    _num(r.outside.n, "d", f"{k}:outside_n"),
                    _num(r.outside.mean_pct, ".3f", f"{k}:outside_mean_pct"),
                    *_coverage_cells(r, k),
                ]
            body.append("<tr>" + "".join(cells) + "</tr>")
        tables += (
            f"<h3>{_e(m)}</h3>"
            f'<div class="tw"><table class="validation"><tr>{head}</tr>{"".join(body)}</table></div>'
        )
    return (
        "<p>Mean |e_Th| ± std in % of the throttle range (seed paper Table 3 layout), on the "
        f"map's selection and loss ({_e(rd.tmap.loss)}). Held out: <b>by-file</b> leaves each "
        "file out in turn, <b>kfold</b> 5 random folds. The held-out figures count every held-out point; "
        "those inside and outside the training points' supported region (extrapolation) are "
        "shown beside them, with the share of them each fold's 95 % prediction interval held "
        "(coverage) and its median half-width. "
        "Same numbers as <code>thrustmap compare --json</code>."
        "</p>" + tables
    )


def _coverage(rd: ReportData) -> str:
    pi = rd.grid_pi_pct
    txt = ""
    over = rd.tmap.interval_over_region()
    if over is not None and np.isfinite(pi).any():
        inside = rd.tmap.supported_region().contains(rd.grid_t, rd.grid_b)
        outside = pi[~inside & np.isfinite(pi)]
        beyond = (
            f"; outside it, over the rest of the (T, B) box, up to ±{np.max(outside):.2f} %, "
            "widening with the distance from the region"
            if outside.size
            else ""
        )
        txt = (
            f"<p>95 % prediction interval of the {_e(rd.tmap.model)} map over its supported "
            f"region (where the data are): ±{over[0]:.2f}..{over[1]:.2f} % throttle{beyond} "
            "(the same interval as <code>thrustmap fit</code> and <code>predict</code>: held-out "
            "residuals and the coefficients' uncertainty at each point)."
        )
        if rd.suggestion:
            txt += (
                f" Widest where the motor can reach (throttle within 0..100 %) at "
                f"T = {rd.suggestion[0]:.2f} N, B = {rd.suggestion[1]:.2f} V: one more test "
                "there would help most."
            )
        txt += "</p>"
    return _img("coverage", rd, "coverage and prediction interval") + txt + _evidence(rd)


def _evidence(rd: ReportData) -> str:
    """How far outside the supported region the interval is backed: the growth, the limit,
    and the extrapolation benchmark's coverage table."""
    iv = rd.tmap.prediction_interval()
    growth = EXTRAPOLATION_GROWTH if iv is None or not iv.growth_per_reach else iv.growth_per_reach
    limit_t = EVIDENCE_LIMIT_THRUST_RATIO if iv is None else iv.limit_thrust_ratio
    limit_v = EVIDENCE_LIMIT_VOLTAGE_LOG if iv is None else iv.limit_voltage_log
    rows = [
        [
            _td(b.rigs),
            _td(
                f"T/reach {b.lo:.2f}–{b.hi:.2f}"
                if b.axis == "thrust"
                else f"|ln B/B_measured| {b.lo:.2f}–{b.hi:.2f}"
            ),
            _num(b.n, "d", f"evidence.{b.rigs}.{b.axis}.{b.lo:g}.n"),
            _num(b.median_error_pct, ".2f", f"evidence.{b.rigs}.{b.axis}.{b.lo:g}.error"),
            _num(b.coverage_pct, ".1f", f"evidence.{b.rigs}.{b.axis}.{b.lo:g}.coverage"),
            _num(b.coverage_main_pct, ".1f", f"evidence.{b.rigs}.{b.axis}.{b.lo:g}.main"),
        ]
        for b in EVIDENCE
    ]
    table = _table(
        ["rigs", "distance outside the region", "n", "median |error| %", "coverage %", "main %"],
        rows,
    )
    return (
        "<h3>How far outside the data the interval is backed</h3>"
        f"<p>In the figure above the dashed curves are the map outside its supported region, "
        f"with their band. Beyond the thrust the data reached at a voltage the interval widens "
        f"by ×(1 + {growth:.2f}·√(T/reach − 1)); {_e(rd.tmap.model)} answers are backed by "
        f"the extrapolation benchmark up to {limit_t:g}× the reach and |ln(B/B<sub>measured</sub>)| "
        f"{limit_v:g} ({100 * math.expm1(limit_v):.0f} % off the voltages measured); past that, "
        "<code>thrustmap predict</code> refuses without <code>--extrapolate</code>. The "
        "benchmark's held-out points (maps fitted on the lower part of a recording, at one "
        "voltage, or on one recording; scored on the rest), the coverage with this interval and "
        f"with the one before (main %): <code>{_e(COMMAND)}</code>.</p>" + table
    )


def _gamma(rd: ReportData) -> str:
    g = rd.gamma
    if g is None:
        return (
            "<p>This map has no γ(B) flight correction (see <code>thrustmap gamma fit</code>).</p>"
        )
    m = g.metrics
    terms = f"{g.coefficients[0]:.6g}" + "".join(
        f" {'−' if c < 0 else '+'} {abs(c):.6g}·B" + (f"^{k}" if k > 1 else "")
        for k, c in enumerate(g.coefficients)
        if k
    )
    out = (
        f"<p>γ(B) = {_e(terms)} (degree {len(g.coefficients) - 1}, loss {_e(g.loss)}), "
        f"flown {g.voltage_v[0]:.2f}..{g.voltage_v[1]:.2f} V; {_e(m.get('validation', ''))}. "
        f"T_c from: {_e(m.get('thrust_cmd_source', ''))}.</p>"
    )
    if g.note:
        out += f'<p class="note">{_e(g.note)}</p>'
    out += _img("gamma", rd, "gamma fit")

    def ms(key: str) -> str:
        v = m.get(key) or {}
        if not v:
            return "<td>–</td>"
        return (
            f'<td data-key="{key}" data-value="{v["mean"]!r}" data-std="{v["std"]!r}">'
            f"{v['mean']:.3f} ± {v['std']:.3f}</td>"
        )

    label = rd.map_label
    out += "<h3>Table 4 layout</h3>" + _table(
        ("map", "e_Th (%)", "e_T (%)", "e_T (N)"),
        [
            [_td(label), ms("e_Th_before_pct"), ms("e_T_before_pct"), ms("e_T_before_n")],
            [_td(f"{label} + γ(B)"), ms("e_Th_after_pct"), ms("e_T_after_pct"), ms("e_T_after_n")],
        ],
    )
    out += "<h3>Errors by voltage (Figs. 8–9)</h3>" + _img("errors-by-voltage", rd, "errors")
    check = m.get("no_worse_check") or {}
    if check:
        floor = check.get("min_bin_samples", 20)
        said = [
            f"Degree {r['degree']} was worse than the uncorrected map at "
            + "; ".join(
                f"{w['voltage_v'][0]:.2f}..{w['voltage_v'][1]:.2f} V ({w['samples']} samples, "
                f"{w['metric']} {w['before_pct']:.3f} → {w['after_pct']:.3f} %)"
                for w in r["worse"]
            )
            for r in check.get("rejected", [])
        ]
        out += (
            f'<p class="note">No-worse check ({_e(check.get("metric", ""))}, voltage bins with '
            f"{floor}+ samples): kept {_e(check.get('kept', ''))}."
            + (" " + _e(". ".join(said)) + "." if said else "")
            + "</p>"
        )
    rows = []
    for i, b in enumerate(m.get("by_voltage", [])):
        cells = [
            _td(f"{b['voltage_v'][0]:.2f}..{b['voltage_v'][1]:.2f}"),
            _num(b["samples"], "d", f"bin{i}:samples"),
            _num(b["gamma"].get("mean"), ".4f", f"bin{i}:gamma"),
        ]
        for k in ("e_Th_before_pct", "e_Th_after_pct", "e_T_before_pct", "e_T_after_pct"):
            cells.append(_num(b.get(k, {}).get("mean"), ".3f", f"bin{i}:{k}"))
        rows.append(cells)
    out += _table(
        ("voltage (V)", "n", "γ", "e_Th before %", "e_Th after %", "e_T before %", "e_T after %"),
        rows,
    )
    return out


def _exports(rd: ReportData) -> str:
    if not rd.exports:
        return "<p>No exports computed.</p>"
    rows = []
    for e in rd.exports:
        params = ", ".join(f"{k} = {v}" for k, v in e.values.items()) or e.note
        resid = ", ".join(f"{k} {v:.3g}" for k, v in e.residual.items()) or "–"
        rows.append([_td(e.target), _td(params), _td(resid)])
    return (
        _map_values(rd)
        + "<p>Each firmware's own thrust-curve form fitted to this map (defaults of "
        "<code>thrustmap export</code>), with the residual its curve leaves (% throttle).</p>"
        + _table(("target", "parameters", "residual"), rows)
    )


def _map_values(rd: ReportData) -> str:
    """The values every export writes, computed once from the map (``fitting.mapvalues``)."""
    if rd.map_values is None:
        return ""
    rows = [
        [
            _td(v.name),
            _td(f"{v.value:.4g} {v.unit}"),
            _td(v.interval_text()),
            _td(f"{v.voltage_v:.4g} V"),
            _td(
                ("EXTRAPOLATED (outside the supported region)" if v.extrapolated else "inside")
                + (f"; {v.basis}" if v.basis else "")
            ),
        ]
        for v in rd.map_values.all()
    ]
    return (
        "<p>The map's values every export writes (in its own units), computed once: the same "
        "numbers as <code>thrustmap predict</code>.</p>"
        + _table(("value", "map", "95 % interval", "at", "where"), rows)
    )


def render_html(rd: ReportData) -> str:
    """The whole report as one HTML document (no external references)."""
    builders = {
        "provenance": _provenance,
        "sweeps": _sweeps,
        "surface": _surface,
        "residuals": _residuals,
        "validation": _validation,
        "coverage": _coverage,
        "gamma": _gamma,
        "exports": _exports,
    }
    nav = "".join(f'<a href="#{k}">{_e(NAV.get(k, t))}</a>' for k, t in SECTIONS)
    body = []
    for key, title in SECTIONS:
        body.append(f'<section id="{key}"><h2>{_e(title)}</h2>{builders[key](rd)}</section>')
    notes = "".join(f'<p class="note">{_e(n)}</p>' for n in rd.notes)
    t = rd.tmap
    return (
        '<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>thrustmap report: {_e(rd.map_path)}</title><style>{CSS}</style></head><body>"
        f"<header><h1>Thrust map report</h1><p>{_e(rd.map_path)} · {_e(t.strategy)} · model "
        f"{_e(t.model)} · thrustmap {_e(rd.tool_version)}</p></header><nav>{nav}</nav>"
        f"<main>{notes}{''.join(body)}</main><script>{JS}</script></body></html>\n"
    )


def write_report(rd: ReportData, output: str) -> int:
    """Write the report atomically; returns its size in bytes."""
    from thrustmap.core.files import atomic_write_text

    text = render_html(rd)
    atomic_write_text(output, text)
    return len(text.encode("utf-8"))
