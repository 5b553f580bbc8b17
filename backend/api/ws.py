"""Websockets ``/ws/tests/{id}`` and ``/ws/live``: schema v1 (docs/architecture.md), hello first.

Read-only, no token. After ``hello`` a client gets the recent history (``samples`` of the last seconds and
the latest ``status``), then everything live. A client that cannot keep up is skipped ahead by the hub;
it never slows the rig. An unknown test gets ``{"v":1,"type":"error","message":...}`` and close code 4404.
"""

from __future__ import annotations

import asyncio
import contextlib

from fastapi import APIRouter, WebSocket, WebSocketDisconnect
from starlette.concurrency import run_in_threadpool

from .. import store
from ..stream import SCHEMA_VERSION, Frame

router = APIRouter()


def _record(app, test_id: int | None) -> dict | None:
    if test_id is None:
        return None
    with app.state.sessions() as session:
        test = store.get_test(session, test_id)
        return store.test_record(session, test) if test is not None else None


def _status_from_record(record: dict) -> dict:
    running = record["status"] == "running"
    stops = [e["values"]["ends_at_s"] for e in record.get("events") or []
             if (e.get("values") or {}).get("ends_at_s") is not None]
    end_s = stops[-1] if stops else record["duration_s"]  # a stop's ramp-out ends the test sooner
    return {"v": SCHEMA_VERSION, "type": "status", "test_id": record["id"], "status": record["status"],
            "time_s": record["time_s"], "progress": record["progress"],
            "cycle": min(record["cycles_done"] + (1 if running else 0), record["cycles_total"]),
            "cycles_total": record["cycles_total"],
            "time_left_s": max(0.0, end_s - record["time_s"]) / record["speed"] if running else 0.0,
            **({"reason": record["reason"]} if record.get("reason") else {})}


async def _serve(websocket: WebSocket, test_id: int | None) -> None:
    app = websocket.app
    hub = app.state.hub
    await websocket.accept()
    target = test_id if test_id is not None else hub.live_test_id
    record = await run_in_threadpool(_record, app, target)
    if test_id is not None and record is None:
        await websocket.send_json({"v": SCHEMA_VERSION, "type": "error", "message": f"test {test_id} does not exist"})
        await websocket.close(code=4404)
        return
    subscription = hub.subscribe(test_id)
    try:
        await websocket.send_text(Frame({"v": SCHEMA_VERSION, "type": "hello", "test_id": target,
                                         "test": record}).text())
        if record is not None and target not in hub.last_status:
            await websocket.send_text(Frame(_status_from_record(record)).text())

        async def forward():
            async for frame in subscription:
                await websocket.send_text(frame.text())

        async def watch():  # returns when the client goes away
            with contextlib.suppress(WebSocketDisconnect):
                while True:
                    message = await websocket.receive()
                    if message["type"] == "websocket.disconnect":
                        return

        tasks = [asyncio.create_task(forward()), asyncio.create_task(watch())]
        _done, pending = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        for task in pending:
            task.cancel()
        for task in pending:
            with contextlib.suppress(asyncio.CancelledError, WebSocketDisconnect, RuntimeError):
                await task
    except (WebSocketDisconnect, RuntimeError):
        pass
    finally:
        subscription.close()


@router.websocket("/ws/tests/{test_id}")
async def ws_test(websocket: WebSocket, test_id: int) -> None:
    await _serve(websocket, test_id)


@router.websocket("/ws/live")
async def ws_live(websocket: WebSocket) -> None:
    await _serve(websocket, None)
