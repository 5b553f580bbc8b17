"""backend.viewer: the switch, the HTTP relay of viser's client and the websocket relay (no browser)."""

from __future__ import annotations

from fastapi import FastAPI
from fastapi.testclient import TestClient

from backend import viewer
from backend.stream import Hub


class _Settings:
    viewer = True


def test_viewer_switch(monkeypatch):
    monkeypatch.delenv("ISORIG_VIEWER", raising=False)
    assert viewer.viewer_enabled(_Settings()) is True
    off = _Settings()
    off.viewer = False
    assert viewer.viewer_enabled(off) is False
    monkeypatch.setenv("ISORIG_VIEWER", "0")
    assert viewer.viewer_enabled(_Settings()) is False
    monkeypatch.setenv("ISORIG_VIEWER", "1")
    assert viewer.viewer_enabled(off) is True


def test_disabled_viewer_only_answers_status(monkeypatch):
    monkeypatch.setenv("ISORIG_VIEWER", "off")
    app = FastAPI()
    assert viewer.attach(app, Hub(), _Settings()) is None
    with TestClient(app) as client:
        assert client.get("/viewer/status").json()["enabled"] is False
        assert client.get("/viewer/").status_code == 404


def test_relay_serves_viser_and_its_websocket(monkeypatch):
    monkeypatch.setenv("ISORIG_VIEWER", "1")
    app = FastAPI()
    hub = Hub()
    relay = viewer.attach(app, hub, _Settings())
    try:
        with TestClient(app) as client:
            assert client.get("/viewer/status").json()["enabled"] is True
            page = client.get("/viewer/")
            assert page.status_code == 200
            assert "text/html" in page.headers["content-type"]
            assert "Viser" in page.text
            assert relay.scene is not None
            assert client.get("/viewer/../etc/passwd").status_code == 404
            with client.websocket_connect("/viewer", subprotocols=["viser-v" + _viser_version()]) as ws:
                first = ws.receive_bytes()  # viser's initial scene state, relayed as binary messages
                assert len(first) > 0
                assert relay.watchers == 1
            # the scene moves with the measured displacement: the isolator's bottom face shifts, its top stays
            for _ in range(viewer.LABEL_EVERY):
                relay.scene.show(0.03, 2.0e4)
            v = relay.scene.isolator.vertices
            n = viewer.N_SIDES
            shift = float(relay.scene.mag.value) * 0.03
            assert abs(v[:n, 0].mean() - (0.8 + shift)) < 1e-6
            assert abs(v[n:2 * n, 0].mean() - 0.8) < 1e-6
            assert relay.scene.table.position[0] == shift
            assert "+30.0 mm" in relay.scene.label.text
    finally:
        relay.close()


def _viser_version() -> str:
    import viser

    return viser.__version__
