"""Timing figures of a real-time loop without lists that grow: a fixed histogram of 10 us bins up to 100 ms.

Adding a value costs one index and one increment, whatever the test's length; percentiles are read off
the cumulative counts to the bin width (10 us), the maximum exactly.
"""

from __future__ import annotations

import math
from itertools import accumulate

BIN_MS = 0.01
TOP_MS = 100.0


class LatencyHistogram:
    """Durations in milliseconds: ``add(ms)``, then ``summary()`` (n, p50, p99, max, count above a bound). The
    counts are a Python list: an add is a list index, not a NumPy scalar's (~4 us on a loaded machine; a real-time
    loop adds several a period)."""

    def __init__(self):
        self.counts = [0] * (int(TOP_MS / BIN_MS) + 1)
        self.n = 0
        self.max_ms = 0.0
        self.total_ms = 0.0  # for the mean

    def add(self, ms: float) -> None:
        if not ms >= 0.0:  # NaN or negative (a clock step): counted as 0
            ms = 0.0
        i = int(ms / BIN_MS)
        self.counts[i if i < len(self.counts) else -1] += 1
        self.n += 1
        self.total_ms += ms
        if ms > self.max_ms:
            self.max_ms = ms

    @property
    def mean_ms(self) -> float:
        """The mean of the values added (exact: their sum, not the bins'); NaN before the first."""
        return self.total_ms / self.n if self.n else float("nan")

    def percentile_ms(self, q: float) -> float:
        """The upper edge of the bin holding the q-th percentile (0 < q <= 100)."""
        if self.n == 0:
            return float("nan")
        rank = max(math.ceil(q / 100.0 * self.n), 1)
        for i, total in enumerate(accumulate(self.counts)):
            if total >= rank:
                return min((i + 1) * BIN_MS, self.max_ms) if i < len(self.counts) - 1 else self.max_ms
        return self.max_ms

    def above(self, ms: float) -> int:
        """How many values were above ``ms`` (to the bin width)."""
        return sum(self.counts[int(ms / BIN_MS) + 1:])

    def summary(self, above_ms: float | None = None) -> dict:
        if self.n == 0:
            return {"n": 0}
        out = {"n": self.n, "p50_ms": self.percentile_ms(50), "p99_ms": self.percentile_ms(99), "max_ms": self.max_ms}
        if above_ms is not None:
            out[f"over_{above_ms:g}_ms"] = self.above(above_ms)
        return out
