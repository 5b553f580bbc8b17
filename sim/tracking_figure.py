"""The one tracking figure of a test, in words (issue 34 item 2; defined in docs/metrics.md, "The tracking figure").

Every command, the test page and the report show the figure of the test's tracking verdict
(``summary.tracking_verdict``, sim.follow.tracking_verdict) under the same name and definition, taken from here.
Any other |y - r| figure shown beside it is named ``raw`` (the reading against the target of the same instant:
it includes the sensor latency, and the taper cycles where it is taken over the whole test). Kept free of heavy
imports: the CLI prints it without loading the reports."""

from __future__ import annotations

NAME = "tracking error"
#: what the figure of a sine or protocol test is (a block per amplitude level; the worst block's figure)
DEFINITION = "RMS of reading - target one latency earlier, last two steady cycles, % of amplitude"
#: ... and of a time history or hybrid test (sim.hybrid_metrics' J2)
HISTORY_DEFINITION = "J2: RMS of reading - target over the test, % of the target's RMS"
#: the name of a figure that is not the tracking figure: |y - r| at the same instant, over the whole test
RAW_NAME = "raw |y - r| (same-instant target: incl. latency and taper)"


def definition(verdict: dict | None) -> str:
    """The few words that say what the verdict's figure is."""
    basis = str((verdict or {}).get("basis", ""))
    return HISTORY_DEFINITION if basis.startswith("J2") else DEFINITION


def tracking_text(verdict: dict | None) -> str:
    """The verdict's words with its definition: "followed: 0.0454 % (within the 0.1 % target) [RMS of ...]"."""
    v = verdict or {}
    words = v.get("words") or "not judged"
    if v.get("verdict") in (None, "not_judged"):
        return words
    return f"{words} [{definition(v)}]"


def tracking_line(verdict: dict | None) -> str:
    """The line every command prints: "tracking error: followed: 0.0454 % (...) [RMS of reading - ...]"."""
    return f"{NAME}: {tracking_text(verdict)}"
