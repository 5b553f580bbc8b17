"""The live stream hub: fans the worker's messages out to websocket clients (and the 3D viewer).

Messages are dicts of websocket schema v1 (docs/architecture.md). ``hub.subscribe(test_id)`` returns a
``Subscription``, an async iterator of messages; ``None`` follows whatever the rig runs. A new subscriber
first gets the recent history (``samples`` of the last ``history_s`` seconds of test time and the latest
``status``). Publishing never waits for a client: each subscriber has a bounded queue, and a client that
falls behind is skipped ahead (its queued ``samples`` are dropped, other messages kept, ``skipped`` counts
the dropped ones). The hub lives on the server's event loop; the service's reader thread publishes through
``publish_threadsafe``.
"""

from __future__ import annotations

import asyncio
import json
import math
from collections import deque

SCHEMA_VERSION = 1
QUEUE_FRAMES = 400  # ~8 s of samples batches at 50 per second


def sample_labels(controller: str | None) -> list[str]:
    """What a ``samples`` message's columns hold for a test of ``controller``, one label per column of
    ``columns`` (the stable keys, sim.samples.CSV_FIELDS): the key, or ``KEY: NAME (UNIT)`` where the controller
    reports another quantity than the MRAC's the key is named after (the servo's ``as_hat: learned frequency
    (Hz)``); the header cells of the test's data.csv (sim.records.column_labels)."""
    from sim.records import column_labels
    from sim.samples import CSV_FIELDS

    return column_labels(controller, CSV_FIELDS)


class Frame(dict):
    """A message dict that serialises itself once for all clients (NaN and infinities become null)."""

    _text: str | None = None

    def text(self) -> str:
        if self._text is None:
            raw = json.dumps(self, separators=(",", ":"), allow_nan=True)
            if self.get("type") == "samples":  # only numbers there: safe to rewrite the tokens
                raw = raw.replace("-Infinity", "null").replace("Infinity", "null").replace("NaN", "null")
            self._text = raw
        return self._text


class Subscription:
    """One client's view of the stream; iterate with ``async for message in subscription``."""

    def __init__(self, hub: Hub, test_id: int | None, maxsize: int = QUEUE_FRAMES):
        self.hub = hub
        self.test_id = test_id
        self.maxsize = maxsize
        self.queue: deque[Frame] = deque()
        self.skipped = 0
        self.closed = False
        self._wakeup = asyncio.Event()

    def wants(self, test_id: int | None) -> bool:
        return self.test_id is None or self.test_id == test_id

    def offer(self, frame: Frame) -> None:
        if self.closed:
            return
        if len(self.queue) >= self.maxsize:  # slow client: skip ahead over queued samples
            kept = deque(f for f in self.queue if f.get("type") != "samples")
            self.skipped += len(self.queue) - len(kept)
            self.queue = kept
            if len(self.queue) >= self.maxsize:
                self.skipped += len(self.queue)
                self.queue.clear()
        self.queue.append(frame)
        self._wakeup.set()

    def __aiter__(self):
        return self

    async def __anext__(self) -> Frame:
        while not self.queue:
            if self.closed:
                raise StopAsyncIteration
            self._wakeup.clear()
            await self._wakeup.wait()
        return self.queue.popleft()

    def close(self) -> None:
        self.closed = True
        self.hub.subscriptions.discard(self)
        self._wakeup.set()


class Hub:
    """Fan-out of stream messages with a short history per test."""

    def __init__(self, history_s: float = 10.0):
        self.history_s = history_s
        self.loop: asyncio.AbstractEventLoop | None = None
        self.subscriptions: set[Subscription] = set()
        self.history: dict[int, deque[Frame]] = {}
        self.last_status: dict[int, Frame] = {}
        self.live_test_id: int | None = None
        self.seq: dict[int, int] = {}

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop = loop

    # --- publishing ----------------------------------------------------------------------------------
    def publish_threadsafe(self, message: dict) -> None:
        if self.loop is not None and not self.loop.is_closed():
            try:
                self.loop.call_soon_threadsafe(self.publish, message)
            except RuntimeError:  # loop closed during shutdown
                pass

    def publish(self, message: dict) -> None:
        frame = message if isinstance(message, Frame) else Frame(message)
        frame.setdefault("v", SCHEMA_VERSION)
        test_id = frame.get("test_id")
        kind = frame.get("type")
        if kind == "samples":
            self._remember(test_id, frame)
        elif kind == "status":
            self.last_status[test_id] = frame
            if frame.get("status") == "running":
                if self.live_test_id != test_id:
                    self.history = {k: v for k, v in self.history.items() if k == test_id}
                self.live_test_id = test_id
        for sub in list(self.subscriptions):
            if sub.wants(test_id):
                sub.offer(frame)

    def next_seq(self, test_id: int) -> int:
        self.seq[test_id] = self.seq.get(test_id, 0) + 1
        return self.seq[test_id]

    def _remember(self, test_id: int, frame: Frame) -> None:
        frames = self.history.setdefault(test_id, deque())
        frames.append(frame)
        rows = frame.get("rows") or []
        if rows:
            newest = rows[-1][0]
            while len(frames) > 1:
                oldest_rows = frames[0].get("rows") or []
                last_t = oldest_rows[-1][0] if oldest_rows else -math.inf
                if newest - last_t > self.history_s:
                    frames.popleft()
                else:
                    break

    # --- subscribing ---------------------------------------------------------------------------------
    def subscribe(self, test_id: int | None) -> Subscription:
        """A subscription to one test (or ``None``: live), primed with the recent history."""
        sub = Subscription(self, test_id)
        target = test_id if test_id is not None else self.live_test_id
        if target is not None:
            for frame in self.history.get(target, ()):
                sub.offer(frame)
            if target in self.last_status:
                sub.offer(self.last_status[target])
        self.subscriptions.add(sub)
        return sub

    def forget(self, test_id: int) -> None:
        self.history.pop(test_id, None)
        self.last_status.pop(test_id, None)
        self.seq.pop(test_id, None)
        if self.live_test_id == test_id:
            self.live_test_id = None
