"""The stream hub: history for late joiners, skip-ahead of slow clients, JSON without NaN."""

from __future__ import annotations

import asyncio
import json
import math

import aio

from backend.stream import Frame, Hub


def samples(test_id, t0, n=20, seq=1):
    return {"type": "samples", "test_id": test_id, "seq": seq, "columns": ["time_s", "x"],
            "rows": [[t0 + i * 1e-3, math.nan if i == 0 else 1.0] for i in range(n)]}


def drain(sub):
    out = []
    while sub.queue:
        out.append(sub.queue.popleft())
    return out


def test_frame_json_has_no_nan_and_versions():
    text = Frame({"v": 1, **samples(1, 0.0, 2)}).text()
    data = json.loads(text)
    assert data["rows"][0][1] is None and data["rows"][1][1] == 1.0
    assert "NaN" not in text


def test_late_joiner_gets_recent_history_then_live():
    hub = Hub(history_s=1.0)
    hub.publish({"type": "status", "test_id": 3, "status": "running"})
    for k in range(100):  # 2 s of test time in 20 ms batches
        hub.publish(samples(3, k * 0.02, seq=k + 1))
    sub = hub.subscribe(3)
    got = drain(sub)
    batches = [f for f in got if f["type"] == "samples"]
    assert got[-1]["type"] == "status"
    assert batches[0]["rows"][0][0] >= 2.0 - 1.0 - 0.021 and batches[-1]["seq"] == 100
    hub.publish(samples(3, 2.0, seq=101))
    hub.publish(samples(4, 0.0))  # another test: not for this subscriber
    assert [f["seq"] for f in drain(sub)] == [101]
    live = hub.subscribe(None)
    assert drain(live)[-1]["type"] == "status"
    hub.publish(samples(4, 0.0))
    assert drain(live)[0]["test_id"] == 4


def test_slow_client_is_skipped_ahead_and_never_blocks():
    hub = Hub()
    sub = hub.subscribe(1)
    sub.maxsize = 10
    hub.publish({"type": "event", "test_id": 1, "kind": "operator", "message": "start"})
    for k in range(35):
        hub.publish(samples(1, k * 0.02, seq=k + 1))
    got = drain(sub)
    assert len(got) <= 10 and sub.skipped >= 25
    assert got[0]["type"] == "event"  # non-sample messages survive a skip
    assert got[-1]["seq"] == 35  # and the client is at the newest data


def test_subscription_iterates_and_closes():
    async def main():
        hub = Hub()
        hub.bind(asyncio.get_running_loop())
        sub = hub.subscribe(1)
        hub.publish_threadsafe(samples(1, 0.0))
        first = await asyncio.wait_for(sub.__anext__(), 1.0)
        sub.close()
        assert sub not in hub.subscriptions
        try:
            await asyncio.wait_for(sub.__anext__(), 1.0)
        except StopAsyncIteration:
            return first
        raise AssertionError("closed subscription kept iterating")

    assert aio.run(main())["type"] == "samples"
