"""The pages of a history or hybrid test: the J criteria with their targets and the command against the measured
displacement (the whole test, the tracking error, the seconds around the largest command, the force against the
displacement), and for a hybrid test the structure's response beside the full-numerical reference and the
stability monitor. The figures come from ``content.earthquake_figures`` (sim.earthquake.record_figures).
"""

from __future__ import annotations

import numpy as np

from ..units import LAB
from .data import num
from .figures import _minmax_decimate
from .header import GREEN, RED, criteria_rows
from .layout import A4_PORTRAIT_IN, draw_lines, fmt_num, wrap_text

ZOOM_S = 0.03  # the close-up where the command is fastest spans this long (30 samples)
REFERENCE_COLOUR = "0.72"  # drawn wide and light under the RTHS line: where they agree, a grey halo shows
REFERENCE_LW = 2.6


def _sentence(text: str) -> str:
    return (text[:1].upper() + text[1:] + ("" if text.endswith(".") else ".")) if text else ""


def _early_end(ax, figures: dict) -> None:
    judged = figures.get("judged") or {}
    if "early end" in str(judged.get("what", "")) or "closed loop" in str(judged.get("what", "")):
        ax.axvline(judged["until_s"], color=RED, lw=0.9, ls="--")


def page_criteria(plt, bundle, figures: dict, u=LAB):
    """The J criteria (value, target, met) and the command against the measurement, in the lab's units ``u``."""
    s = bundle.samples
    fig = plt.figure(figsize=A4_PORTRAIT_IN)
    kind = figures.get("kind")
    title = "Time history: tracking criteria" if kind == "history" else "Hybrid simulation: tracking criteria"
    fig.text(0.06, 0.955, title, fontsize=12, weight="bold")
    lines = []
    for text, colour in criteria_rows(figures):
        lines.append((text, {GREEN: GREEN, RED: RED}.get(colour, "black")))
    if not figures.get("verdicts"):
        lines.append(("no criteria: " + str((figures.get("judged") or {}).get("note") or figures.get("note")
                                            or "too few samples"), RED))
    judged = figures.get("judged") or {}
    notes = [f"J1-J3 compare the target r (the command) with the measured displacement y over {judged.get('what', '')}"
             f" ({judged.get('samples', 0)} samples; RTHS benchmark, Silva et al. 2020)."]
    if kind == "hybrid":
        notes.append("J4-J5 compare the structure's base displacement with the full-numerical reference (next page).")
    if figures.get("note"):
        notes.append(f"Note: {figures['note']}.")
    for note in notes:
        lines += [(w, "0.35") for w in wrap_text(note, 118)]
    draw_lines(fig, lines, 0.06, 0.94, 7.6, 10.0)
    top = 0.94 - (len(lines) + 1) * 10.0 / 72.0 / A4_PORTRAIT_IN[1]
    outer = fig.add_gridspec(2, 1, left=0.1, right=0.96, top=top - 0.02, bottom=0.06, hspace=0.2,
                             height_ratios=[2.0, 1.3])
    upper = outer[0].subgridspec(2, 1, hspace=0.16, height_ratios=[1.2, 0.8])
    lower = outer[1].subgridspec(1, 2, wspace=0.28)
    ax_t = fig.add_subplot(upper[0])
    ax_e = fig.add_subplot(upper[1], sharex=ax_t)
    ax_z = fig.add_subplot(lower[0])
    ax_fd = fig.add_subplot(lower[1])
    t = s["time_s"]
    to_length, to_force = u.factor("length"), u.factor("force")
    length, force = u.unit("length"), u.unit("force")
    r, y, f = s["target_m"] * to_length, s["displacement_m"] * to_length, s["force_n"] * to_force
    td, rd, yd, ed = _minmax_decimate(t, r, y, y - r)
    ax_t.plot(td, rd, color=REFERENCE_COLOUR, lw=REFERENCE_LW, label="command (target r)")
    ax_t.plot(td, yd, color="C0", lw=0.6, label="measured y")
    ax_t.tick_params(labelbottom=False)
    ax_t.set_ylabel(f"displacement [{length}]")
    ax_t.set_title("Command and measured displacement", loc="left")
    ax_t.legend(loc="upper right")
    ax_e.plot(td, ed, color="C3", lw=0.7)
    ax_e.set_ylabel(f"y - r [{length}]")
    ax_e.set_xlabel("time [s]")
    ax_e.set_title("Tracking error", loc="left")
    for ax in (ax_t, ax_e):
        _early_end(ax, figures)
    n_judged = int(judged.get("samples") or 0)
    rate = np.abs(np.diff(r[:n_judged])) if n_judged > 2 else np.zeros(0)
    if rate.size and np.isfinite(rate).any():
        k = int(np.nanargmax(rate))  # where the command moves fastest: a delay shows there
        sel = (t >= t[k] - ZOOM_S / 2) & (t <= t[k] + ZOOM_S / 2)
        ax_z.plot(t[sel], r[sel], color="0.45", lw=1.0, marker="o", ms=2.2, mfc="none", label="command r")
        ax_z.plot(t[sel], y[sel], color="C0", lw=0.8, marker=".", ms=2.5, label="measured y")
        ax_z.legend(loc="best")
        delay = num((figures.get("criteria") or {}).get("j1_delay_ms"))
        ax_z.set_title(f"Where the command is fastest: every sample (J1 {fmt_num(delay, '{:.3f}')} ms)", loc="left",
                       fontsize=8.5)
    ax_z.set_xlabel("time [s]")
    ax_z.set_ylabel(f"displacement [{length}]")
    step = max(1, t.size // 20000)
    ax_fd.plot(y[::step], f[::step], color="C0", lw=0.5)
    ax_fd.set_xlabel(f"displacement y [{length}]")
    ax_fd.set_ylabel(f"force [{force}]")
    ax_fd.set_title("Force against displacement (whole test)", loc="left", fontsize=8.5)
    ax_fd.axhline(0, color="0.6", lw=0.5)
    ax_fd.axvline(0, color="0.6", lw=0.5)
    return fig


def page_hybrid(plt, bundle, figures: dict, u=LAB):
    """The structure's response (replayed from the record) beside the full-numerical reference, the isolator's
    hysteresis, and the stability monitor, in the lab's units ``u``."""
    arrays = figures.get("arrays") or {}
    fig = plt.figure(figsize=A4_PORTRAIT_IN)
    fig.text(0.06, 0.955, "Hybrid simulation: the structure and its full-numerical reference", fontsize=12,
             weight="bold")
    structure = figures.get("structure") or {}
    peaks = structure.get("peaks") or {}
    lines = [f"{'channel':<24}{'RTHS peak':>12}{'reference':>12}{'difference':>12}   (peaks over the same time)"]
    quantities = {"_m": "length", "_m_per_s2": "acceleration", "_n": "force"}
    for name, p in peaks.items():
        q = next(v for k, v in sorted(quantities.items(), key=lambda kv: -len(kv[0])) if name.endswith(k))
        a, b = num(p.get("rths")), num(p.get("reference"))
        diff = f"{100 * (a / b - 1):+.2f} %" if a is not None and b else "-"
        label = name.removesuffix("_m_per_s2").removesuffix("_m").removesuffix("_n") + f" [{u.unit(q)}]"
        lines.append(f"{label:<24}{u.fmt(q, a, sig=4):>12}{u.fmt(q, b, sig=4):>12}{diff:>12}")
    rep = figures.get("replay") or {}
    ref = figures.get("reference") or {}
    notes = [f"RTHS: the structure's response over its {structure.get('periods', 0)} periods, rebuilt from the "
             f"recorded force and position (sim.hybrid.replay; largest difference from the recorded commands "
             f"{u.text('length', num(rep.get('command_difference_m')), sig=2)}). "
             + _sentence(str(ref.get("note") or ref.get("what") or "")),
             f"The structure's record ends at t = {fmt_num(structure.get('until_s'), '{:.3f}')} s with a base "
             f"displacement of {u.text('length', num(structure.get('residual_base_displacement_m')))}."]
    text = [(line, "black") for line in lines] + [("", "black")]
    for note in notes:
        text += [(w, "0.35") for w in wrap_text(note, 118)]
    draw_lines(fig, text, 0.06, 0.94, 7.6, 10.0)
    top = 0.94 - (len(text) + 1) * 10.0 / 72.0 / A4_PORTRAIT_IN[1]
    gs = fig.add_gridspec(4, 2, left=0.1, right=0.96, top=top - 0.015, bottom=0.06, hspace=0.55, wspace=0.28)
    rths = arrays.get("structure") or {}
    whole = arrays.get("reference_whole") or {}
    t_s = arrays.get("structure_time_s")
    n_ref = len(next(iter(whole.values()))) if whole else 0
    t_ref = np.arange(n_ref) * 1e-3
    names = list(rths)
    drifts = [n for n in names if n.startswith("drift_")]
    accs = [n for n in names if n.startswith("abs_acc_") and n != "abs_acc_base_m_per_s2"]
    plots = [("base_displacement_m", "Base displacement (the rig's command)", u.unit("length"), u.factor("length")),
             (drifts[0] if drifts else None, "First-storey drift", u.unit("length"), u.factor("length")),
             (drifts[-1] if drifts else None, "Top-storey drift", u.unit("length"), u.factor("length")),
             (accs[-1] if accs else None, "Top-storey absolute acceleration", u.unit("acceleration"),
              u.factor("acceleration"))]
    axes = [fig.add_subplot(gs[0, :]), fig.add_subplot(gs[1, 0]), fig.add_subplot(gs[1, 1]), fig.add_subplot(gs[2, :])]
    for ax, (name, title, unit, scale) in zip(axes, plots, strict=True):
        if name is None or name not in whole or t_s is None:
            ax.set_axis_off()
            continue
        tr, vr = _minmax_decimate(t_ref, whole[name] * scale)
        ax.plot(tr, vr, color=REFERENCE_COLOUR, lw=REFERENCE_LW, ls="-", label="reference (offline)")
        if len(t_s):
            ts, vs = _minmax_decimate(t_s, rths[name] * scale)
            ax.plot(ts, vs, color="C0", lw=0.6, label="RTHS")
        ax.set_title(title, loc="left", fontsize=8.5)
        ax.set_ylabel(f"[{unit}]")
        ax.set_xlabel("time [s]")
        _early_end(ax, figures)
    axes[0].legend(loc="upper right")
    ax_h = fig.add_subplot(gs[3, 0])
    if "isolator_force_n" in whole and len(rths.get("isolator_force_n", [])):
        step = max(1, n_ref // 20000)
        ax_h.plot(whole["base_displacement_m"][::step] * u.factor("length"),
                  whole["isolator_force_n"][::step] * u.factor("force"),
                  color=REFERENCE_COLOUR, lw=REFERENCE_LW * 0.8, label="reference")
        m = len(rths["isolator_force_n"])
        step = max(1, m // 20000)
        ax_h.plot(rths["base_displacement_m"][::step] * u.factor("length"),
                  rths["isolator_force_n"][::step] * u.factor("force"), color="C0",
                  lw=0.5, label="RTHS (measured)")
        ax_h.legend(loc="upper left", fontsize=6.5)
    ax_h.set_title("Isolator force against base displacement", loc="left", fontsize=8.5)
    ax_h.set_xlabel(f"base displacement [{u.unit('length')}]")
    ax_h.set_ylabel(f"force [{u.unit('force')}]")
    ax_s = fig.add_subplot(gs[3, 1])
    energy, limit = arrays.get("added_energy_j"), arrays.get("limit_j")
    stab = figures.get("stability") or {}
    if energy is not None and t_s is not None and len(energy):
        ax_s.plot(t_s, energy, color="C3", lw=0.8, label="E_err (replayed)")
        ax_s.plot(t_s, limit, color="0.3", lw=0.8, ls="--", label="limit")
        trip = num(stab.get("trip_time_s"))
        if stab.get("tripped") and trip is not None:
            ax_s.axvline(trip, color=RED, lw=0.9)
            ax_s.annotate("tripped", (trip, 0.08), xycoords=("data", "axes fraction"), xytext=(-3, 0),
                          textcoords="offset points", ha="right", fontsize=7, color=RED)
        ax_s.legend(loc="upper left", fontsize=6.5)
    ax_s.set_title("Stability monitor: energy added by the tracking error", loc="left", fontsize=8.5)
    ax_s.set_xlabel("time [s]")
    ax_s.set_ylabel("[J]")
    return fig


def pages_earthquake(plt, bundle, figures: dict, u=LAB) -> list:
    figs = [page_criteria(plt, bundle, figures, u)]
    if figures.get("kind") == "hybrid" and figures.get("arrays"):
        figs.append(page_hybrid(plt, bundle, figures, u))
    return figs
