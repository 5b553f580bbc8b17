"""HELLO's rate (docs/rig-protocol.md section 9.6): a token bucket per source, in a table of bounded size.

Each source (address, port) has its own bucket: ``burst`` tokens, ``rate_per_s`` more each second, one taken by
each HELLO whose tag is then checked. A source the table does not hold starts with a full bucket; when the
table is full, it takes the place of the least recently seen source (which starts full again if it comes back).
So only datagrams from the host's own address and port can use up the host's HELLOs: a flood from any other
source, spoofed or not, leaves it its whole bucket, and nothing needs to be reserved for it. What the bound costs:
a flood from more sources than the table holds has every datagram's tag checked (measured in section 9.6).

Standard library only: a lab's real-time target in C does the same with a fixed array and a last-seen time.
"""

from __future__ import annotations

from collections import OrderedDict

HELLO_BURST = 10  # HELLOs answered at once at most, per source ...
HELLO_RATE_PER_S = 100.0  # ... and on average; the rest are dropped as `rate` before their tag is checked
HELLO_SOURCES = 64  # sources whose buckets are kept (1.5 kB in C); a new one replaces the least recently seen


class HelloBuckets:
    """Per-source token buckets for HELLO; ``take(source, now_s)`` says whether this HELLO may have its tag
    checked (and, if it verifies, an answer)."""

    def __init__(self, burst: int = HELLO_BURST, rate_per_s: float = HELLO_RATE_PER_S,
                 max_sources: int = HELLO_SOURCES):
        if burst < 1 or rate_per_s <= 0 or max_sources < 1:
            raise ValueError(f"a HELLO bucket needs burst >= 1 ({burst!r}), rate > 0 /s ({rate_per_s!r}) and room "
                             f"for at least 1 source ({max_sources!r})")
        self.burst, self.rate_per_s, self.max_sources = float(burst), rate_per_s, max_sources
        self.table: OrderedDict[object, list[float]] = OrderedDict()  # source -> [tokens, time_s], oldest first
        self.evicted = 0  # sources forgotten to make room

    def take(self, source, now_s: float) -> bool:
        """One token from ``source``'s bucket at time ``now_s`` (s); False: none left (drop as `rate`)."""
        entry = self.table.get(source)
        if entry is None:
            if len(self.table) >= self.max_sources:
                self.table.popitem(last=False)  # the least recently seen source
                self.evicted += 1
            entry = self.table[source] = [self.burst, now_s]
        else:
            self.table.move_to_end(source)
            entry[0] = min(self.burst, entry[0] + max(0.0, now_s - entry[1]) * self.rate_per_s)
            entry[1] = now_s
        if entry[0] < 1.0:
            return False
        entry[0] -= 1.0
        return True

    def status(self) -> dict:
        return {"sources": len(self.table), "max_sources": self.max_sources, "evicted": self.evicted,
                "burst": int(self.burst), "rate_per_s": self.rate_per_s}
