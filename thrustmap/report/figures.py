"""The report's figures (matplotlib, Agg): the seed paper's Figs. 5-9 and the map diagnostics.

Every function takes a :class:`ReportData` and returns a matplotlib Figure; ``FIGURES`` names
them for ``thrustmap plot``. matplotlib is imported here only, never by the CLI at start-up; figures are drawn
without pyplot (Agg canvas, no global state).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import matplotlib
import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from thrustmap.fitting.extrapolation import EVIDENCE_LIMIT_THRUST_RATIO
from thrustmap.report.data import ReportData

STYLE: dict[str, Any] = {
    "font.size": 9,
    "axes.titlesize": 10,
    "axes.labelsize": 9,
    "legend.fontsize": 8,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "figure.dpi": 100,
    "savefig.bbox": "tight",
}

TH = "throttle (% of scale)"
T = "thrust per rotor (N)"
B = "battery voltage (V)"


def _fig(w: float = 7.0, h: float = 4.0, **kw: Any) -> Figure:
    # No layout engine: constrained layout costs seconds on many-axes figures; savefig's
    # bbox_inches="tight" (STYLE) trims the margins in one pass.
    return Figure(figsize=(w, h), **kw)


def render(name: str, rd: ReportData, fmt: str = "png", dpi: int = 100) -> bytes:
    """Draw figure ``name`` (a key of FIGURES) in the report style and return the file bytes.
    Figures are drawn without pyplot (no global state, no GUI backend)."""
    import io

    with matplotlib.rc_context(STYLE):  # type: ignore[arg-type]
        fig = FIGURES[name](rd)
        buf = io.BytesIO()
        fig.savefig(buf, format=fmt, dpi=dpi)
    return buf.getvalue()


def sweep(rd: ReportData) -> Figure:
    """Raw sweeps over time, with what steady-state selection kept and dropped (paper Fig. 5)."""
    n = len(rd.datasets)
    fig = _fig(7.5, 1.9 * n + 0.6)
    axes = fig.subplots(n, 1, squeeze=False)[:, 0]
    fig.subplots_adjust(hspace=0.45)
    for ax, ds, mask in zip(axes, rd.datasets, rd.masks, strict=True):
        x = ds.time_s if ds.time_s is not None else np.arange(len(ds), dtype=float)

        # Masked lines (NaN outside each role) draw thousands of samples fast and stay legible.
        def part(m: Any, y: Any = ds.thrust_n) -> Any:
            return np.where(m, y, np.nan)

        ramp = mask.other & ~np.isclose(np.gradient(ds.throttle_pct), 0.0)
        ax.plot(x, ds.thrust_n, color="0.8", lw=0.6, label="thrust, all samples")
        ax.plot(
            x,
            part(ramp),
            color="tab:green",
            lw=1.0,
            label="ramp / transition (ramp pairs: see counts)",
        )
        ax.plot(x, part(mask.settling), color="tab:red", lw=1.6, label="dropped: settling")
        ax.plot(x, part(mask.kept), color="tab:blue", lw=1.6, label="kept: settled plateau")
        if mask.stair_pair is not None and mask.stair_pair.any():
            ax.plot(
                x,
                part(mask.stair_pair),
                color="tab:purple",
                lw=1.6,
                label="kept: stairs paired up/down",
            )
        ax.set_ylabel("T (N)")
        ax.set_title(ds.name, loc="left")
        tw = ax.twinx()
        tw.plot(x, ds.throttle_pct, color="tab:orange", lw=0.8, alpha=0.8)
        tw.set_ylabel("Th (%)", color="tab:orange")
        tw.grid(False)
    axes[-1].set_xlabel("time (s)" if rd.datasets[-1].time_s is not None else "sample")
    fig.legend(
        *axes[0].get_legend_handles_labels(),
        loc="upper center",
        ncol=4,
        bbox_to_anchor=(0.5, -0.02),
        frameon=False,
    )
    return fig


def surface(rd: ReportData) -> Figure:
    """The fitted surface Th(T, B) with the selected points on it (paper Fig. 6)."""
    fig = _fig(6.5, 5.0)
    ax: Any = fig.add_subplot(projection="3d")
    ax.plot_surface(
        rd.grid_t, rd.grid_b, rd.grid_th, cmap="viridis", alpha=0.6, lw=0, rcount=30, ccount=30
    )
    p = rd.points
    ax.scatter(
        p.thrust_n,
        p.voltage_v,
        p.throttle_pct,
        s=4,
        c="k",
        depthshade=False,
        label="selected points",
    )
    ax.set_xlabel(T)
    ax.set_ylabel(B)
    ax.set_zlabel(TH)
    ax.set_title(f"{rd.map_label}, model {rd.tmap.model}")
    ax.yaxis.set_major_locator(MaxNLocator(5))
    ax.view_init(elev=22, azim=-130)
    ax.legend(loc="upper left")
    return fig


def slices(rd: ReportData, n_voltages: int = 4) -> Figure:
    """Throttle against thrust at several voltages, with the points near each voltage: solid
    with its 95 % band inside the supported region, dashed with its (wider) band where the map
    extrapolates, up to the benchmark's evidence limit (or full throttle)."""
    fig = _fig(6.5, 4.2)
    ax = fig.subplots()
    tmap = rd.tmap
    region = tmap.supported_region()
    volts = np.linspace(region.voltage_lo_v, region.voltage_hi_v, n_voltages)
    half_step = (volts[1] - volts[0]) / 2 if n_voltages > 1 else np.inf
    iv = tmap.prediction_interval()
    limit = EVIDENCE_LIMIT_THRUST_RATIO if iv is None else iv.limit_thrust_ratio
    p = rd.points
    cmap = matplotlib.colormaps["plasma"]
    for k, b in enumerate(volts):
        color = cmap(k / max(n_voltages - 1, 1) * 0.85)
        t_lo, t_hi = (float(x) for x in region.thrust_range(b))
        t_full = float(tmap.thrust_n(100.0, b, corrected=False))
        t_end = max(min(limit * t_hi, t_full if np.isfinite(t_full) else limit * t_hi), t_hi)
        for part, (a, z) in enumerate(((t_lo, t_hi), (t_hi, t_end))):
            if z <= a:
                continue
            t = np.linspace(a, z, 120)
            bb = np.full_like(t, b)
            th = tmap.throttle_pct(t, bb, corrected=False)
            ax.plot(
                t,
                th,
                "-" if part == 0 else "--",
                color=color,
                lw=1.5,
                label=f"map at {b:.2f} V" if part == 0 else None,
            )
            half = tmap.interval_pct(t, bb, corrected=False)
            if half is not None:
                ax.fill_between(
                    t, th - half, th + half, color=color, alpha=0.18 if part else 0.3, lw=0
                )
        near = np.abs(p.voltage_v - b) <= half_step
        ax.plot(p.thrust_n[near], p.throttle_pct[near], "o", ms=2.5, color=color, alpha=0.6)
    ax.plot([], [], "--", color="0.4", label=f"extrapolated (to {limit:g}× the reach)")
    ax.set_ylim(max(ax.get_ylim()[0], -10.0), min(ax.get_ylim()[1], 110.0))
    ax.set_xlabel(T)
    ax.set_ylabel(TH)
    ax.set_title(
        "bench map (without γ) at several voltages: solid where the data are, dashed where it "
        "extrapolates; bands: 95 % interval",
        fontsize=9,
    )
    ax.legend(fontsize=8)
    return fig


def residuals(rd: ReportData) -> Figure:
    """Map residuals (prediction − measured throttle) against thrust and against voltage."""
    fig = _fig(7.5, 3.2)
    a1, a2 = fig.subplots(1, 2, sharey=True)
    fig.subplots_adjust(wspace=0.08)
    p, r = rd.points, rd.residual_pct
    a1.plot(p.thrust_n, r, ".", ms=3, alpha=0.6)
    a2.plot(p.voltage_v, r, ".", ms=3, alpha=0.6, color="tab:green")
    for ax in (a1, a2):
        ax.axhline(0, color="k", lw=0.8)
    a1.set_xlabel(T)
    a2.set_xlabel(B)
    a1.set_ylabel("residual (% throttle)")
    fig.suptitle(f"residuals of the {rd.tmap.model} map on its selected points")
    return fig


def coverage(rd: ReportData) -> Figure:
    """Where the data is, and the 95 % prediction interval over the (T, B) box."""
    fig = _fig(7.5, 3.6)
    a1, a2 = fig.subplots(1, 2, sharey=True)
    fig.subplots_adjust(wspace=0.08)
    p = rd.points
    v = rd.tmap.validity
    a1.imshow(
        rd.grid_count,
        origin="lower",
        aspect="auto",
        cmap="Blues",
        extent=(v.thrust_n.lo, v.thrust_n.hi, v.voltage_v.lo, v.voltage_v.hi),
    )
    a1.plot(p.thrust_n, p.voltage_v, ".", ms=2, color="k", alpha=0.5)
    a1.set_title("selected points (cells: count)")
    cs = a2.contourf(rd.grid_t, rd.grid_b, rd.grid_pi_pct, levels=12, cmap="magma_r")
    fig.colorbar(cs, ax=a2, label="95 % PI half-width (% throttle)")
    if rd.suggestion is not None:
        a2.plot(
            *rd.suggestion,
            "*",
            ms=14,
            color="tab:cyan",
            mec="k",
            label="widest interval: test here next",
            clip_on=False,
            zorder=5,
        )
        # keep the star whole: a suggestion at the grid's corner gets a margin around it
        t_s, b_s = rd.suggestion
        for (lo, hi), x, setter in (
            (a2.get_xlim(), t_s, a2.set_xlim),
            (a2.get_ylim(), b_s, a2.set_ylim),
        ):
            pad = 0.05 * (max(hi, x) - min(lo, x) or 1.0)
            setter(min(lo, x - pad), max(hi, x + pad))
    a2.set_title("prediction interval")
    region = rd.tmap.supported_region()
    rb = np.linspace(region.voltage_lo_v, region.voltage_hi_v, 50)
    r_lo, r_hi = region.thrust_range(rb)
    outline_t = np.concatenate([r_lo, r_hi[::-1], r_lo[:1]])
    outline_b = np.concatenate([rb, rb[::-1], rb[:1]])
    for ax in (a1, a2):
        ax.plot(outline_t, outline_b, "--", color="tab:green", lw=1.2, label="supported region")
    # one legend below both panels: inside them it covered the star and the data points
    handles, labels = a1.get_legend_handles_labels()
    for h, lab in zip(*a2.get_legend_handles_labels(), strict=True):
        if lab not in labels:
            handles.append(h)
            labels.append(lab)
    fig.subplots_adjust(bottom=0.27)
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), frameon=False)
    for ax in (a1, a2):
        ax.set_xlabel(T)
    a1.set_ylabel(B)
    return fig


def gamma(rd: ReportData) -> Figure:
    """γ(B) with the flight data it was fitted to (paper Fig. 7)."""
    g = rd.gamma
    if g is None:
        raise ValueError("the map has no γ correction")
    fig = _fig(6.0, 3.6)
    ax = fig.subplots()
    if g.sample_gamma is not None and g.sample_voltage_v is not None:
        ax.plot(
            g.sample_voltage_v,
            g.sample_gamma,
            ".",
            ms=3,
            alpha=0.4,
            color="tab:blue",
            label="γ_j = T_c / F_m (Df)",
        )
    b = np.linspace(g.voltage_v[0], g.voltage_v[1], 200)
    curve = np.polynomial.polynomial.polyval(b, g.coefficients)
    ax.plot(b, curve, color="tab:red", lw=2, label=f"γ(B), degree {len(g.coefficients) - 1}")
    ax.set_xlabel(B)
    ax.set_ylabel("γ")
    ax.set_title("correction factor γ(B)")
    ax.legend()
    return fig


def errors_by_voltage(rd: ReportData) -> Figure:
    """e_Th and e_T by voltage bin, uncorrected and corrected (paper Figs. 8-9).

    Both maps are drawn in every bin; a bin with too few samples for the no-worse check is
    drawn hollow, a bin where the corrected map is worse is ringed in red, and a γ degree that
    the check rejected is drawn dashed in the metric it was rejected on."""
    g = rd.gamma
    if g is None:
        raise ValueError("the map has no γ correction")
    bins = g.metrics.get("by_voltage", [])
    check = g.metrics.get("no_worse_check") or {}
    floor = int(check.get("min_bin_samples", 20))
    fig = _fig(7.5, 3.4)
    a1, a2 = fig.subplots(1, 2)
    fig.subplots_adjust(wspace=0.25, bottom=0.2)
    mid = np.array([0.5 * (r["voltage_v"][0] + r["voltage_v"][1]) for r in bins])
    # the two maps side by side within each bin: a fixed offset put them a bin apart in
    # narrow bins, so it is a fraction of the narrowest bin
    widths = [r["voltage_v"][1] - r["voltage_v"][0] for r in bins]
    shift = 0.12 * min((w for w in widths if w > 0), default=0.1)
    few = np.array([r["samples"] < floor for r in bins], dtype=bool)
    kept = str(check.get("kept", ""))
    after_label = "map + γ(B)" + (f", {kept}" if kept else "")
    for ax, key, title in ((a1, "e_Th", "e_Th (% throttle)"), (a2, "e_T", "e_T (% of F_m)")):
        series: dict[str, np.ndarray] = {}
        for when, color, off in (("before", "tab:orange", -shift), ("after", "tab:blue", shift)):
            k = f"{key}_{when}_pct"
            if not bins or k not in bins[0]:
                continue
            m = np.array([r[k]["mean"] for r in bins])
            s = np.array([r[k]["std"] for r in bins])
            series[when] = m
            ax.errorbar(
                mid + off,
                m,
                yerr=s,
                fmt="-",
                capsize=3,
                color=color,
                label="map (uncorrected)" if when == "before" else after_label,
            )
            ax.plot(mid[~few] + off, m[~few], "o", ms=5, color=color)
            ax.plot(mid[few] + off, m[few], "o", ms=5, mfc="white", color=color)
        if "before" in series and "after" in series:
            worse = (series["after"] > series["before"]) & ~few
            if worse.any():
                ax.plot(
                    mid[worse] + shift,
                    series["after"][worse],
                    "o",
                    ms=11,
                    mfc="none",
                    mec="tab:red",
                    mew=1.5,
                    label="corrected worse",
                )
        if check.get("metric") == key:
            for r in check.get("rejected", []):
                after = r.get("by_voltage_after") or []
                if len(after) == len(mid) and f"degree {r['degree']}" != kept:
                    ax.plot(
                        mid,
                        after,
                        "x--",
                        color="tab:gray",
                        label=f"degree {r['degree']} (not kept: worse in {len(r['worse'])} bin"
                        + ("s)" if len(r["worse"]) != 1 else ")"),
                    )
        if few.any():
            ax.plot([], [], "o", mfc="white", color="black", label=f"under {floor} samples")
        ax.set_xlabel(B)
        ax.set_title(title)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
        else:
            ax.text(0.5, 0.5, "not computed", ha="center", va="center", transform=ax.transAxes)
    return fig


FIGURES: dict[str, Callable[[ReportData], Figure]] = {
    "surface": surface,
    "slices": slices,
    "residuals": residuals,
    "coverage": coverage,
    "sweep": sweep,
    "gamma": gamma,
    "errors-by-voltage": errors_by_voltage,
}
