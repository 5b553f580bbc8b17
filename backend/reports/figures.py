"""The plotted pages: force-displacement loops with K_eff and EDC per cycle, time histories, and the detail of
the first and last seconds; ``plot_style`` sets matplotlib up for them (PDF core fonts, sizes, grid).
"""

from __future__ import annotations

import math

import numpy as np

from ..units import LAB
from .data import num
from .layout import A4_PORTRAIT_IN

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
    from .textmetrics import install

    install()  # the core fonts' string widths in fewer steps (the same answers)
    return plt


def _minmax_decimate(t: np.ndarray, *ys: np.ndarray, buckets: int = PLOT_POINTS):
    """Per bucket, the min and the max of each series in time order: peaks survive, ~2 x buckets points. Every
    sample is in a bucket (the last, shorter one takes the rest)."""
    n = t.size
    if n <= 4 * buckets:
        return (t, *ys)
    size = n // buckets
    edges = np.arange(0, n, size)  # bucket starts; the last bucket may be shorter
    full = n // size
    t_out = np.column_stack([t[edges], t[np.minimum(edges + size, n) - 1]]).ravel()
    outs = []
    for y in ys:
        pairs = [_bucket_pairs(y[:full * size].reshape(full, size))]
        if full * size < n:
            pairs.append(_bucket_pairs(y[full * size:].reshape(1, -1)))
        outs.append(np.concatenate(pairs).ravel())
    return (t_out, *outs)


def _bucket_pairs(yy: np.ndarray) -> np.ndarray:
    """(first, second) of each row: its min and max in the order they occur (NaN rows stay NaN)."""
    i_lo = np.argmin(np.where(np.isnan(yy), np.inf, yy), axis=1)
    i_hi = np.argmax(np.where(np.isnan(yy), -np.inf, yy), axis=1)
    rows = np.arange(yy.shape[0])
    lo, hi = yy[rows, i_lo], yy[rows, i_hi]
    return np.where((i_lo <= i_hi)[:, None], np.column_stack([lo, hi]), np.column_stack([hi, lo]))


STEADY_COLOUR_MAP = "viridis"
TAPER_COLOUR = "0.6"


def _is_steady(c: dict) -> bool:
    return c.get("phase", "steady") == "steady"


MIN_SPAN = 0.1  # a per-cycle axis spans at least 10 % of its values' size: 0.1 % scatter is not drawn as a cliff


def steady_limits(values, margin: float = 0.08):
    """Axis limits around the finite ``values`` (those of the steady cycles), at least MIN_SPAN of their largest
    size wide, or None when there are none."""
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], dtype=float)
    if v.size == 0:
        return None
    lo, hi = float(v.min()), float(v.max())
    lo, hi = lo - margin * (hi - lo), hi + margin * (hi - lo)
    least = MIN_SPAN * max(abs(lo), abs(hi)) or 1e-12
    if hi - lo < least:
        mid = 0.5 * (lo + hi)
        lo, hi = mid - 0.5 * least, mid + 0.5 * least
    return lo, hi


def _per_cycle(ax, cycles, key, scale, colour, label, mean):
    """One quantity per cycle: the steady cycles as a line (gaps where a taper is), the tapers as open grey
    markers, the axis scaled to the steady cycles (a taper beyond it drawn at the edge as a triangle), the
    headline mean as a dashed line. Returns how many taper values are off the axis."""
    n = np.array([c["cycle"] for c in cycles], dtype=float)
    v = np.array([(num(c.get(key)) if num(c.get(key)) is not None else np.nan) * scale for c in cycles])
    steady = np.array([_is_steady(c) for c in cycles])
    marker = "o" if len(cycles) <= 80 else None
    ax.plot(n, np.where(steady, v, np.nan), color=colour, marker=marker, ms=3, label=f"{label}, steady cycles")
    limits = steady_limits(v[steady]) or steady_limits(v)
    off = 0
    if (~steady).any():
        tn, tv = n[~steady], v[~steady]
        if limits is not None:
            lo, hi = limits
            inside = (tv >= lo) & (tv <= hi)
            ax.plot(tn[inside], tv[inside], ls="none", marker="o", ms=3.5, mfc="white", mec=colour, alpha=0.75)
            above, below = tv > hi, tv < lo
            ax.plot(tn[above], np.full(above.sum(), hi), ls="none", marker="^", ms=4.5, mfc="white", mec=colour,
                    clip_on=False)
            ax.plot(tn[below], np.full(below.sum(), lo), ls="none", marker="v", ms=4.5, mfc="white", mec=colour,
                    clip_on=False)
            off = int(above.sum() + below.sum())
    if limits is not None:
        ax.set_ylim(*limits)
    if isinstance(mean, list):  # a protocol: each level's mean over its own cycles
        for x0, x1, value in mean:
            if value is not None:
                ax.hlines(value * scale, x0 - 0.5, x1 + 0.5, color=colour, lw=0.7, ls="--", alpha=0.8)
    elif mean is not None:
        ax.axhline(mean * scale, color=colour, lw=0.7, ls="--", alpha=0.8)
    return off


def _level_means(protocol, head: dict, key: str) -> list | None:
    """A protocol's per-level means as (first cycle, last cycle, value), or None for another test."""
    levels = (head or {}).get("levels") or []
    if protocol is None or not levels:
        return None
    plan = protocol.cycle_plan()
    out = []
    for lv in levels:
        numbers = [p["cycle"] for p in plan if p["level"] == lv["level"]]
        if numbers:
            out.append((min(numbers), max(numbers), (lv.get("means") or {}).get(key)))
    return out


def page_loops(plt, bundle, protocol, report=None, u=LAB):
    """The loops and the per-cycle K_eff and EDC, in the lab's units ``u`` (backend.units.Units)."""
    from matplotlib.collections import LineCollection
    from matplotlib.lines import Line2D

    fig, axes = plt.subplots(2, 1, figsize=A4_PORTRAIT_IN, gridspec_kw={"height_ratios": [3, 2]})
    fig.subplots_adjust(left=0.12, right=0.88, top=0.94, bottom=0.11, hspace=0.3)
    ax = axes[0]
    cycles = [c for c in bundle.cycles if c.get("displacement_m") is not None and len(c["displacement_m"]) > 2]
    means = ((report or {}).get("headline") or {}).get("means") or {}
    if cycles:
        step = max(1, math.ceil(len(cycles) / MAX_LOOPS))
        shown = cycles[::step]
        if shown[-1] is not cycles[-1]:
            shown.append(cycles[-1])
        shown += [c for c in cycles if not _is_steady(c) and not any(c is s for s in shown)]  # every taper
        shown.sort(key=lambda c: c["cycle"])
        segs, tapers = [], []
        for c in shown:
            d = np.asarray(c["displacement_m"]) * u.factor("length")
            f = np.asarray(c["force_n"]) * u.factor("force")
            k = max(1, d.size // LOOP_POINTS)
            (segs if _is_steady(c) else tapers).append(np.column_stack([d[::k], f[::k]]))
        if tapers:
            ax.add_collection(LineCollection(tapers, colors=TAPER_COLOUR, linewidths=0.7, linestyles="--"))
        if segs:
            numbers = np.array([c["cycle"] for c in shown if _is_steady(c)], dtype=float)
            lc = LineCollection(segs, cmap=STEADY_COLOUR_MAP, linewidths=0.8)
            lc.set_array(numbers)
            ax.add_collection(lc)
            cb = fig.colorbar(lc, ax=ax, pad=0.01, fraction=0.04)
            cb.set_label("cycle (steady)")
        ax.autoscale()
        n_taper = sum(1 for c in cycles if not _is_steady(c))
        ax.set_title(f"Force-displacement loops ({len(shown)} of {len(cycles)} cycles shown)")
        if n_taper:
            ax.legend(handles=[Line2D([], [], color=TAPER_COLOUR, lw=0.7, ls="--",
                                      label=f"taper cycles ({n_taper}): not in the headline figures")],
                      loc="upper left")
    else:
        ax.text(0.5, 0.5, "no complete cycle recorded", ha="center", va="center", transform=ax.transAxes)
        ax.set_title("Force-displacement loops")
    ax.set_xlabel(f"displacement [{u.unit('length')}]")
    ax.set_ylabel(f"force [{u.unit('force')}]")
    ax.axhline(0, color="0.6", lw=0.5)
    ax.axvline(0, color="0.6", lw=0.5)
    # per-cycle K_eff and EDC, scaled to the steady cycles
    ax2 = axes[1]
    if bundle.cycles:
        ax2.set_ylabel(f"K_eff [{u.unit('stiffness')}]", color="C0")
        ax3 = ax2.twinx()
        ax3.set_ylabel("EDC [J]", color="C3")
        ax3.grid(False)
        head = (report or {}).get("headline") or {}
        per_level = {k: _level_means(protocol, head, k) for k in ("k_eff_n_per_m", "edc_j")}
        off = _per_cycle(ax2, bundle.cycles, "k_eff_n_per_m", u.factor("stiffness"), "C0", "K_eff",
                         per_level["k_eff_n_per_m"] if per_level["k_eff_n_per_m"] is not None
                         else means.get("k_eff_n_per_m"))
        off += _per_cycle(ax3, bundle.cycles, "edc_j", u.factor("energy"), "C3", "EDC",
                          per_level["edc_j"] if per_level["edc_j"] is not None else means.get("edc_j"))
        title = "Effective stiffness and energy dissipated per cycle"
        if protocol is not None:
            for p in protocol.cycle_plan():
                if p["test"]:
                    ax2.axvspan(p["cycle"] - 0.5, p["cycle"] + 0.5, color="0.92", lw=0, zorder=0)
            title += " (shaded: judged test cycles)"
        ax2.set_title(title)
        handles = [Line2D([], [], color="C0", label="K_eff"), Line2D([], [], color="C3", label="EDC"),
                   Line2D([], [], color="0.3", ls="--", lw=0.7, label="mean of each level's steady cycles"
                          if per_level["k_eff_n_per_m"] is not None else "mean of the steady cycles")]
        if any(not _is_steady(c) for c in bundle.cycles):
            handles.append(Line2D([], [], ls="none", marker="o", ms=3.5, mfc="white", mec="0.3",
                                  label="open: taper cycle (excluded)" + (f"; {off} off scale (triangles)" if off
                                                                          else "")))
        ax2.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.12), fontsize=7, ncol=4,
                   frameon=False, handlelength=1.6, columnspacing=1.2)
        from matplotlib.ticker import MaxNLocator

        ax2.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax2.set_xlabel("cycle")
    fig.text(0.12, 0.036, "Axes scaled to the steady cycles; taper cycles (lower amplitude, stiffer) are drawn "
             "grey and left out of the headline figures.", fontsize=7, color="0.35")
    return fig


def page_time(plt, bundle, u=LAB):
    """Displacement and target, valve command and tracking error over the whole test, in the lab's units ``u``."""
    s = bundle.samples
    fig, axes = plt.subplots(3, 1, figsize=A4_PORTRAIT_IN, sharex=True)
    fig.subplots_adjust(left=0.12, right=0.95, top=0.94, bottom=0.07, hspace=0.18)
    if len(s):
        t = s["time_s"]
        y, r, v = s["displacement_m"] * u.factor("length"), s["target_m"] * u.factor("length"), s["voltage_v"]
        e = y - r
        td, yd, rd, vd, ed = _minmax_decimate(t, y, r, v, e)
        axes[0].plot(td, rd, color="0.55", lw=1.4, label="target r")
        axes[0].plot(td, yd, color="C0", lw=0.7, label="displacement y")
        axes[0].legend(loc="upper right")
        axes[1].plot(td, vd, color="C2", lw=0.7)
        axes[2].plot(td, ed, color="C3", lw=0.7)
        if np.isfinite(e).any():
            rms = float(np.sqrt(np.nanmean(e * e))) / u.factor("length")  # SI, for backend.units
            axes[2].set_title(f"Tracking error y - r (RMS {u.text('length', rms)})", loc="left")
        for ev in bundle.events:
            if ev.get("kind") == "limit_trip" and num(ev.get("time_s")) is not None:
                for ax in axes:
                    ax.axvline(ev["time_s"], color="#c62828", lw=1.0, ls="--")
                axes[0].annotate("limit trip", (ev["time_s"], 1.0), xycoords=("data", "axes fraction"),
                                 xytext=(-3, -3), textcoords="offset points", ha="right", va="top", fontsize=7,
                                 color="#c62828")
    axes[0].set_title("Displacement and target", loc="left")
    axes[0].set_ylabel(f"displacement [{u.unit('length')}]")
    axes[1].set_title("Servo-valve command voltage", loc="left")
    axes[1].set_ylabel("voltage [V]")
    axes[2].set_ylabel(f"y - r [{u.unit('length')}]")
    axes[2].set_xlabel("time [s]")
    return fig


def page_time_detail(plt, bundle, u=LAB):
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
        scale = u.factor("length")
        y, r, v = s["displacement_m"][sel] * scale, s["target_m"][sel] * scale, s["voltage_v"][sel]
        axes[0, col].plot(tt, r, color="0.55", lw=1.4, label="target r")
        axes[0, col].plot(tt, y, color="C0", lw=0.8, label="displacement y")
        axes[1, col].plot(tt, v, color="C2", lw=0.8)
        axes[2, col].plot(tt, y - r, color="C3", lw=0.8)
        axes[2, col].set_xlabel("time [s]")
        axes[0, col].set_title("start" if col == 0 else "end", loc="left")
    axes[0, 0].legend(loc="upper right")
    axes[0, 0].set_ylabel(f"displacement [{u.unit('length')}]")
    axes[1, 0].set_ylabel("voltage [V]")
    axes[2, 0].set_ylabel(f"y - r [{u.unit('length')}]")
    return fig
