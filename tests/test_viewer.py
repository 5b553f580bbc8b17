"""backend.viewer: the switch, the HTTP relay of viser's client and the websocket relay (no browser)."""

from __future__ import annotations

import os
import stat
import time

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from backend import viewer
from backend.doors import ServiceDoors
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


def _listening_tcp_ports() -> set[tuple[str, int]]:
    """(address, port) of every TCP socket this process listens on (Linux /proc)."""
    inodes = set()
    for fd in os.listdir("/proc/self/fd"):
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    found = set()
    for table in ("/proc/self/net/tcp", "/proc/self/net/tcp6"):
        with open(table) as f:
            for line in f.readlines()[1:]:
                cols = line.split()
                if cols[3] == "0A" and cols[9] in inodes:  # LISTEN
                    address, port = cols[1].rsplit(":", 1)
                    found.add((address, int(port, 16)))
    return found


def test_the_view_is_reached_only_through_the_service_doors(monkeypatch):
    """viser listens on no TCP port (a page re-pointed at 127.0.0.1, whatever Host or Origin it sends, finds
    nothing; issue 33 found its loopback port serving the live scene to Host: evil.example), only on a Unix socket
    in a 0700 directory; the relay behind the doors refuses a foreign Host and a foreign Origin."""
    monkeypatch.setenv("ISORIG_VIEWER", "1")
    app = FastAPI()
    relay = viewer.attach(app, Hub(), _Settings())
    app.add_middleware(ServiceDoors, max_body_bytes=1 << 20, allowed_hosts=["testserver"])
    before = _listening_tcp_ports()
    try:
        with TestClient(app) as client:
            assert client.get("/viewer/").status_code == 200  # starts the scene
            assert _listening_tcp_ports() - before == set()
            socket_dir = relay.scene.socket_dir
            assert stat.S_IMODE(os.stat(socket_dir).st_mode) == 0o700
            assert stat.S_ISSOCK(os.stat(relay.scene.socket_path).st_mode)
            assert client.get("/viewer/", headers={"Host": "evil.example"}).status_code == 400
            protocol = ["viser-v" + _viser_version()]
            with pytest.raises(WebSocketDisconnect):
                with client.websocket_connect("/viewer", subprotocols=protocol,
                                              headers={"Origin": "http://evil.example"}) as ws:
                    ws.receive_bytes()
            with client.websocket_connect("/viewer", subprotocols=protocol,
                                          headers={"Origin": "http://testserver"}) as ws:
                assert len(ws.receive_bytes()) > 0  # its own page gets the scene
        assert relay.scene is None and not os.path.exists(socket_dir)  # closed with the application
    finally:
        relay.close()


def test_a_viser_that_listens_elsewhere_is_not_served(monkeypatch):
    """Should viser start its server some other way (an upgrade), the view is refused, not served on a port."""
    import contextlib

    monkeypatch.setenv("ISORIG_VIEWER", "1")
    monkeypatch.setattr(viewer, "_viser_listens_on", lambda path: contextlib.nullcontext())
    app = FastAPI()
    relay = viewer.attach(app, Hub(), _Settings())
    before = _listening_tcp_ports()
    try:
        with TestClient(app) as client:
            r = client.get("/viewer/")
            assert r.status_code == 503 and "did not listen on its private socket" in r.json()["detail"]
            assert relay.scene is None
    finally:
        relay.close()
    deadline = time.monotonic() + 5
    while _listening_tcp_ports() - before and time.monotonic() < deadline:
        time.sleep(0.1)
    assert _listening_tcp_ports() - before == set()  # the port it opened is closed again


def test_a_killed_service_s_socket_directory_is_removed_by_the_next_view(monkeypatch, tmp_path):
    import socket

    monkeypatch.setattr(viewer.tempfile, "gettempdir", lambda: str(tmp_path))
    dirs = {}
    for kind in ("stale", "live", "new"):
        path = tmp_path / f"{viewer.SOCKET_DIR_PREFIX}{kind}"
        path.mkdir(mode=0o700)
        sock = socket.socket(socket.AF_UNIX)
        sock.bind(str(path / "viser.sock"))
        sock.listen()
        dirs[kind] = (path, sock)
    dirs["stale"][1].close()  # its service was killed: the file stays, nothing listens
    dirs["new"][1].close()  # just made by a service still starting: too young to judge
    old = time.time() - 120
    for kind in ("stale", "live"):
        os.utime(dirs[kind][0], (old, old))
    viewer._remove_stale_sockets()
    assert not dirs["stale"][0].exists()
    assert dirs["live"][0].exists() and dirs["new"][0].exists()
    dirs["live"][1].close()


def _viser_version() -> str:
    import viser

    return viser.__version__
