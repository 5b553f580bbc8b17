"""The plotted pages: force-displacement loops with K_eff and EDC per cycle, time histories, and the detail of
the first and last seconds; ``plot_style`` sets matplotlib up for them (PDF core fonts, sizes, grid).
"""

from __future__ import annotations

import math

import numpy as np

from .data import num
from .layout import A4_PORTRAIT_IN, footer

PLOT_POINTS = 2500  # min/max buckets per time history (5000 points: peaks kept, file small)
MAX_LOOPS = 40  # loops drawn in the overview (evenly chosen; all of them if fewer)
LOOP_POINTS = 400  # points per drawn loop
DETAIL_WINDOW_S = 5.0  # long records get a page with the first and last seconds at full resolution


def plot_style():
    """pyplot, with the report's style (core PDF fonts, sizes, grid) and the Agg backend."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    plt.rcParams.update({"font.size": 8.5, "axes.titlesize": 10, "axes.labelsize": 8.5, "legend.fontsize": 7.5,
                         "xtick.labelsize": 7.5, "ytick.labelsize": 7.5, "axes.grid": True, "grid.alpha": 0.3,
                         "lines.linewidth": 0.8, "pdf.compression": 6, "path.simplify": True,
                         # the PDF's 14 core fonts: no glyph embedding, text pages render ~10x faster
                         "pdf.use14corefonts": True, "font.family": "sans-serif",
                         "font.sans-serif": ["Helvetica"], "font.monospace": ["Courier"],
                         "axes.unicode_minus": False})
    return plt


def _minmax_decimate(t: np.ndarray, *ys: np.ndarray, buckets: int = PLOT_POINTS):
    """Per bucket, the min and the max of each series in time order: peaks survive, ~2 x buckets points."""
    n = t.size
    if n <= 4 * buckets:
        return (t, *ys)
    size = n // buckets
    m = size * buckets
    t_out = t[:m].reshape(buckets, size)[:, [0, -1]].ravel()
    outs = []
    for y in ys:
        yy = y[:m].reshape(buckets, size)
        i_lo = np.argmin(np.where(np.isnan(yy), np.inf, yy), axis=1)
        i_hi = np.argmax(np.where(np.isnan(yy), -np.inf, yy), axis=1)
        rows = np.arange(buckets)
        lo, hi = yy[rows, i_lo], yy[rows, i_hi]
        pair = np.where((i_lo <= i_hi)[:, None], np.column_stack([lo, hi]), np.column_stack([hi, lo]))
        outs.append(pair.ravel())
    return (t_out, *outs)


def page_loops(plt, bundle, protocol, page):
    from matplotlib.collections import LineCollection

    fig, axes = plt.subplots(2, 1, figsize=A4_PORTRAIT_IN, gridspec_kw={"height_ratios": [3, 2]})
    fig.subplots_adjust(left=0.12, right=0.88, top=0.94, bottom=0.07, hspace=0.28)
    ax = axes[0]
    cycles = [c for c in bundle.cycles if c.get("displacement_m") is not None and len(c["displacement_m"]) > 2]
    if cycles:
        step = max(1, math.ceil(len(cycles) / MAX_LOOPS))
        shown = cycles[::step]
        if shown[-1] is not cycles[-1]:
            shown.append(cycles[-1])
        segs = []
        for c in shown:
            d = np.asarray(c["displacement_m"]) * 1e3
            f = np.asarray(c["force_n"]) * 1e-3
            k = max(1, d.size // LOOP_POINTS)
            segs.append(np.column_stack([d[::k], f[::k]]))
        numbers = np.array([c["cycle"] for c in shown], dtype=float)
        lc = LineCollection(segs, cmap="viridis", linewidths=0.8)
        lc.set_array(numbers)
        ax.add_collection(lc)
        ax.autoscale()
        cb = fig.colorbar(lc, ax=ax, pad=0.01, fraction=0.04)
        cb.set_label("cycle")
        ax.set_title(f"Force-displacement loops ({len(shown)} of {len(cycles)} cycles shown)")
    else:
        ax.text(0.5, 0.5, "no complete cycle recorded", ha="center", va="center", transform=ax.transAxes)
        ax.set_title("Force-displacement loops")
    ax.set_xlabel("displacement [mm]")
    ax.set_ylabel("force [kN]")
    ax.axhline(0, color="0.6", lw=0.5)
    ax.axvline(0, color="0.6", lw=0.5)
    # per-cycle K_eff and EDC
    ax2 = axes[1]
    if bundle.cycles:
        n = [c["cycle"] for c in bundle.cycles]
        keff = [(num(c.get("k_eff_n_per_m")) or np.nan) * 1e-6 for c in bundle.cycles]
        edc = [num(c.get("edc_j")) if num(c.get("edc_j")) is not None else np.nan for c in bundle.cycles]
        marker = "o" if len(n) <= 80 else None
        ax2.plot(n, keff, color="C0", marker=marker, ms=3, label="K_eff")
        ax2.set_ylabel("K_eff [kN/mm]", color="C0")
        ax3 = ax2.twinx()
        ax3.plot(n, edc, color="C3", marker=marker, ms=3, label="EDC")
        ax3.set_ylabel("EDC [J]", color="C3")
        ax3.grid(False)
        title = "Effective stiffness and energy dissipated per cycle"
        if protocol is not None:
            for p in protocol.cycle_plan():
                if p["test"]:
                    ax2.axvspan(p["cycle"] - 0.5, p["cycle"] + 0.5, color="0.92", lw=0, zorder=0)
            title += " (shaded: judged test cycles)"
        ax2.set_title(title)
        from matplotlib.ticker import MaxNLocator

        ax2.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax2.set_xlabel("cycle")
    footer(fig, bundle.record, page)
    return fig


def page_time(plt, bundle, page):
    s = bundle.samples
    fig, axes = plt.subplots(3, 1, figsize=A4_PORTRAIT_IN, sharex=True)
    fig.subplots_adjust(left=0.12, right=0.95, top=0.94, bottom=0.07, hspace=0.18)
    if len(s):
        t = s["time_s"]
        y, r, u = s["displacement_m"] * 1e3, s["target_m"] * 1e3, s["voltage_v"]
        e = y - r
        td, yd, rd, ud, ed = _minmax_decimate(t, y, r, u, e)
        axes[0].plot(td, rd, color="0.55", lw=1.4, label="target r")
        axes[0].plot(td, yd, color="C0", lw=0.7, label="displacement y")
        axes[0].legend(loc="upper right")
        axes[1].plot(td, ud, color="C2", lw=0.7)
        axes[2].plot(td, ed, color="C3", lw=0.7)
        if np.isfinite(e).any():
            rms = float(np.sqrt(np.nanmean(e * e)))
            axes[2].set_title(f"Tracking error y - r (RMS {rms:.3f} mm)", loc="left")
        for ev in bundle.events:
            if ev.get("kind") == "limit_trip" and num(ev.get("time_s")) is not None:
                for ax in axes:
                    ax.axvline(ev["time_s"], color="#c62828", lw=1.0, ls="--")
    axes[0].set_title("Displacement and target", loc="left")
    axes[0].set_ylabel("displacement [mm]")
    axes[1].set_title("Servo-valve command voltage", loc="left")
    axes[1].set_ylabel("voltage [V]")
    axes[2].set_ylabel("y - r [mm]")
    axes[2].set_xlabel("time [s]")
    footer(fig, bundle.record, page)
    return fig


def page_time_detail(plt, bundle, page):
    """First and last DETAIL_WINDOW_S seconds at full resolution (the overview page is an envelope)."""
    s = bundle.samples
    t = s["time_s"]
    fig, axes = plt.subplots(3, 2, figsize=A4_PORTRAIT_IN, sharey="row")
    fig.subplots_adjust(left=0.12, right=0.95, top=0.93, bottom=0.07, hspace=0.25, wspace=0.08)
    fig.suptitle(f"Detail: the first and the last {DETAIL_WINDOW_S:g} s", fontsize=11, weight="bold", y=0.975)
    windows = [(t[0], t[0] + DETAIL_WINDOW_S), (t[-1] - DETAIL_WINDOW_S, t[-1])]
    for col, (a, b) in enumerate(windows):
        sel = (t >= a) & (t <= b)
        tt = t[sel]
        y, r, u = s["displacement_m"][sel] * 1e3, s["target_m"][sel] * 1e3, s["voltage_v"][sel]
        axes[0, col].plot(tt, r, color="0.55", lw=1.4, label="target r")
        axes[0, col].plot(tt, y, color="C0", lw=0.8, label="displacement y")
        axes[1, col].plot(tt, u, color="C2", lw=0.8)
        axes[2, col].plot(tt, y - r, color="C3", lw=0.8)
        axes[2, col].set_xlabel("time [s]")
        axes[0, col].set_title("start" if col == 0 else "end", loc="left")
    axes[0, 0].legend(loc="upper right")
    axes[0, 0].set_ylabel("displacement [mm]")
    axes[1, 0].set_ylabel("voltage [V]")
    axes[2, 0].set_ylabel("y - r [mm]")
    footer(fig, bundle.record, page)
    return fig
