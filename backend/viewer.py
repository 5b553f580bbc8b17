"""3D rig view: a viser scene of the rig driven by the live stream, relayed through the service under /viewer/.

viser runs its own HTTP + websocket server; here it listens on a Unix socket in a directory only the service's
user may enter (0700), never on a TCP port, and the service relays ``GET /viewer/...`` and the websocket at
``/viewer`` to it, so the view is reached only through the service's doors (Host allow-list, Origin) and the
dashboard embeds it under its own origin. No browser can reach a Unix socket, whatever Host or Origin it sends.
The share button is hidden and share requests are dropped in the relay and disabled on the server: nothing
reaches an outside host.

The scene (metres, z up, actuator axis x): base, reaction wall, cylinder and rod, sliding table on rails,
a round isolator between the table and the fixed top beam that shears with the measured displacement (its
bottom face moves with the table, its top stays), and a force indicator (bar length and colour follow the
measured force). Updates are throttled (UPDATE_PERIOD_S) and batched: the browser applies each as React
state changes, which is what costs time when WebGL runs in software.

Switch the view off with ``ISORIG_VIEWER=0`` (or a ``viewer`` setting set to False): then only
``GET /viewer/status`` answers ``{"enabled": false}`` and no viser server is started.
"""

from __future__ import annotations

import asyncio
import atexit
import contextlib
import glob
import inspect
import logging
import math
import os
import shutil
import socket
import stat
import tempfile
import threading
import time

import httpx
import websockets
import websockets.asyncio.client
import websockets.asyncio.server
from fastapi import Request, WebSocket, WebSocketDisconnect
from fastapi.responses import JSONResponse, RedirectResponse, Response

log = logging.getLogger(__name__)

UPDATE_PERIOD_S = 1.0 / 20.0  # scene updates per second at most (each costs the browser a React update)
LABEL_EVERY = 4  # the text readout changes on every 4th scene update
N_SIDES = 32  # facets of the drawn isolator
DRAW = {  # geometry in metres
    "table_z": 0.55,  # top of the sliding table
    "isolator_h": 0.30,
    "isolator_r": 0.30,
    "rod_z": 0.45,
}
FORCE_FULL_SCALE_N = 5.0e4  # force bar length 1 m at this force (grows if exceeded)
SOCKET_DIR_PREFIX = "isorig-viewer-"  # viser's Unix socket: <tmp>/isorig-viewer-XXXX/viser.sock


def viewer_enabled(settings) -> bool:
    """The 3D view is on unless ISORIG_VIEWER is 0/false/no/off or settings.viewer is False."""
    env = os.environ.get("ISORIG_VIEWER")
    if env is not None:
        return env.strip().lower() not in ("0", "false", "no", "off", "")
    value = getattr(settings, "viewer", None)
    if value is None:
        value = getattr(settings, "viewer_enabled", True)
    return bool(value)


def _quat_about_y(angle_rad: float) -> tuple[float, float, float, float]:
    return (math.cos(angle_rad / 2), 0.0, math.sin(angle_rad / 2), 0.0)


def isolator_mesh(shift_m: float, radius_m: float, height_m: float, z0_m: float, x0_m: float):
    """Vertices and faces of a round isolator whose bottom face is shifted by ``shift_m`` along x (simple shear:
    the bottom plate moves with the table, the top is held by the frame)."""
    import numpy as np

    angles = np.linspace(0.0, 2 * math.pi, N_SIDES, endpoint=False)
    ring = np.stack([radius_m * np.cos(angles), radius_m * np.sin(angles)], axis=1)
    bottom = np.column_stack([ring[:, 0] + x0_m + shift_m, ring[:, 1], np.full(N_SIDES, z0_m)])
    top = np.column_stack([ring[:, 0] + x0_m, ring[:, 1], np.full(N_SIDES, z0_m + height_m)])
    centres = np.array([[x0_m + shift_m, 0.0, z0_m], [x0_m, 0.0, z0_m + height_m]])
    vertices = np.vstack([bottom, top, centres]).astype(np.float32)
    faces = []
    cb, ct = 2 * N_SIDES, 2 * N_SIDES + 1
    for k in range(N_SIDES):
        j = (k + 1) % N_SIDES
        faces += [(k, j, N_SIDES + j), (k, N_SIDES + j, N_SIDES + k), (cb, j, k), (ct, N_SIDES + k, N_SIDES + j)]
    return vertices, np.array(faces, dtype=np.uint32)


class ViewerError(RuntimeError):
    """The 3D view could not be started as it must be (on its private Unix socket)."""


class _Shim:
    """A module as seen by viser: its own attributes, some replaced."""

    def __init__(self, real, **replaced):
        self._real, self._replaced = real, replaced

    def __getattr__(self, name):
        return self._replaced[name] if name in self._replaced else getattr(self._real, name)


_START_LOCK = threading.Lock()


@contextlib.contextmanager
def _viser_listens_on(path: str):
    """While a viser server starts: the websockets server it creates listens on the Unix socket ``path`` instead
    of the host and port it names (viser has no option for it; only viser's module sees the change)."""
    import rich
    from viser.infra import _infra

    real_serve = websockets.asyncio.server.serve

    def serve(handler, host=None, port=None, **kwargs):
        return real_serve(handler, unix=True, path=path, **kwargs)

    shim = _Shim(websockets, asyncio=_Shim(websockets.asyncio,
                                           server=_Shim(websockets.asyncio.server, serve=serve)))
    console = rich.get_console()  # viser prints its URLs, host:port, which name no socket of ours: not shown
    with _START_LOCK:
        saved, quiet = _infra.websockets, console.quiet
        _infra.websockets, console.quiet = shim, True
        try:
            yield
        finally:
            _infra.websockets, console.quiet = saved, quiet


def _remove_stale_sockets(min_age_s: float = 60.0) -> None:
    """Remove this user's socket directories of views whose service is gone (killed: nothing listens any more)."""
    for path in glob.glob(os.path.join(tempfile.gettempdir(), SOCKET_DIR_PREFIX + "*")):
        try:
            info = os.stat(path)
            if info.st_uid != os.getuid() or time.time() - info.st_mtime < min_age_s:
                continue
            with socket.socket(socket.AF_UNIX) as probe:
                probe.settimeout(0.5)
                probe.connect(os.path.join(path, "viser.sock"))
        except (FileNotFoundError, ConnectionRefusedError):
            shutil.rmtree(path, ignore_errors=True)
        except OSError:
            continue


class RigScene:
    """The viser server and the scene handles that move; ``show(displacement_m, force_n)`` updates them."""

    def __init__(self, magnification: float = 3.0):
        import viser

        _remove_stale_sockets()
        self.socket_dir = tempfile.mkdtemp(prefix=SOCKET_DIR_PREFIX)  # 0700: only the service's user enters
        atexit.register(shutil.rmtree, self.socket_dir, ignore_errors=True)
        self.socket_path = os.path.join(self.socket_dir, "viser.sock")
        try:
            with _viser_listens_on(self.socket_path):
                self.server = viser.ViserServer(host="127.0.0.1", port=0, label="isorig rig", verbose=False)
        except BaseException:
            shutil.rmtree(self.socket_dir, ignore_errors=True)
            raise
        if not (os.path.exists(self.socket_path) and stat.S_ISSOCK(os.stat(self.socket_path).st_mode)):
            self.stop()  # it listens somewhere else (a viser that starts its server otherwise): refuse to serve
            raise ViewerError(f"viser {viser.__version__} did not listen on its private socket; the 3D view stays "
                              "off (ISORIG_VIEWER=0 hides it)")
        # never open a share tunnel, whatever a client asks
        self.server.request_share_url = lambda *args, **kwargs: None
        self.server.gui.configure_theme(show_share_button=False, show_logo=False, dark_mode=True,
                                        control_width="small")
        self.magnification = magnification
        self.force_scale_n = FORCE_FULL_SCALE_N
        self._lock = threading.Lock()
        self._updates = 0
        self._push = True
        self._build()

    def _build(self) -> None:
        s = self.server.scene
        z_t = DRAW["table_z"]
        s.set_up_direction("+z")
        # shadows re-render a shadow map on every move: too slow where WebGL runs in software
        s.configure_default_lights(enabled=True, cast_shadow=False)
        s.configure_environment_map(hdri=None)  # no image-based lighting: cheaper per pixel
        s.add_light_ambient("/light/ambient", intensity=1.2)
        s.add_light_directional("/light/key", intensity=2.5, position=(2.0, -3.0, 4.0), cast_shadow=False)
        s.add_light_directional("/light/fill", intensity=0.8, position=(-3.0, 2.0, 2.0), cast_shadow=False)
        s.add_grid("/grid", width=8.0, height=6.0, cell_size=0.5, position=(0.0, 0.0, 0.0))
        s.add_box("/base", color=(90, 96, 104), dimensions=(4.4, 1.6, 0.2), position=(0.0, 0.0, 0.1))
        s.add_box("/wall", color=(120, 110, 100), dimensions=(0.5, 1.6, 2.2), position=(-2.0, 0.0, 1.2))
        # fixed top beam (reaction of the vertical jack) on two columns
        s.add_box("/frame/col_a", color=(70, 110, 160), dimensions=(0.16, 0.16, 1.9), position=(1.35, -0.7, 1.15))
        s.add_box("/frame/col_b", color=(70, 110, 160), dimensions=(0.16, 0.16, 1.9), position=(1.35, 0.7, 1.15))
        beam_z = z_t + DRAW["isolator_h"] + 0.1
        s.add_box("/frame/beam", color=(70, 110, 160), dimensions=(1.0, 1.6, 0.2), position=(1.0, 0.0, beam_z))
        s.add_box("/frame/jack", color=(150, 150, 160), dimensions=(0.3, 0.3, 1.1), position=(0.8, 0.0, beam_z + 0.65))
        s.add_box("/rails/a", color=(60, 60, 60), dimensions=(2.6, 0.08, 0.1), position=(0.6, -0.45, 0.25))
        s.add_box("/rails/b", color=(60, 60, 60), dimensions=(2.6, 0.08, 0.1), position=(0.6, 0.45, 0.25))
        along_x = _quat_about_y(math.pi / 2)
        s.add_cylinder("/cylinder", radius=0.16, height=1.0, color=(200, 170, 60), wxyz=along_x,
                       position=(-1.25, 0.0, DRAW["rod_z"]))
        # moving parts: the table frame carries the table, the rod and the isolator's bottom plate
        self.table = s.add_frame("/table", show_axes=False, position=(0.0, 0.0, 0.0))
        s.add_box("/table/top", color=(170, 175, 185), dimensions=(1.4, 1.1, 0.2), position=(0.8, 0.0, z_t - 0.1))
        s.add_cylinder("/table/rod", radius=0.05, height=1.3, color=(220, 220, 225), wxyz=along_x,
                       position=(-0.4, 0.0, DRAW["rod_z"]))
        s.add_box("/table/plate", color=(110, 110, 120), dimensions=(0.7, 0.7, 0.03),
                  position=(0.8, 0.0, z_t + 0.015))
        s.add_box("/top_plate", color=(110, 110, 120), dimensions=(0.7, 0.7, 0.03),
                  position=(0.8, 0.0, z_t + DRAW["isolator_h"] - 0.015))
        self.iso_geometry = dict(radius_m=DRAW["isolator_r"], height_m=DRAW["isolator_h"] - 0.06,
                                 z0_m=z_t + 0.03, x0_m=0.8)
        vertices, faces = isolator_mesh(0.0, **self.iso_geometry)
        self.isolator = s.add_mesh_simple("/isolator", vertices=vertices, faces=faces, color=(45, 45, 50),
                                          flat_shading=False, side="double")
        self.force_bar = s.add_box("/force", color=(255, 80, 80), dimensions=(1.0, 0.08, 0.08),
                                   position=(0.8, -0.9, z_t + 0.15), scale=(0.001, 1.0, 1.0))
        self.label = s.add_label("/readout", text="no test", position=(0.2, -0.9, z_t + 0.75))
        self.status = self.server.gui.add_markdown("**no test running**")
        self.mag = self.server.gui.add_slider("displacement x", min=1.0, max=10.0, step=1.0,
                                              initial_value=self.magnification)
        self.server.scene.set_up_direction("+z")
        self.server.initial_camera.position = (0.0, -3.0, 1.4)
        self.server.initial_camera.look_at = (0.6, 0.0, 0.6)

    def show(self, displacement_m: float, force_n: float, text: str | None = None) -> None:
        """Move the table, shear the isolator (bottom moves, top fixed) and set the force bar."""
        if not (math.isfinite(displacement_m) and math.isfinite(force_n)):
            return
        d = displacement_m * float(self.mag.value)
        if abs(force_n) > self.force_scale_n:
            self.force_scale_n = abs(force_n) * 1.25
        length = max(1e-3, abs(force_n) / self.force_scale_n)
        push = force_n >= 0
        vertices, _ = isolator_mesh(d, **self.iso_geometry)
        with self._lock, self.server.atomic():
            self._updates += 1
            self.table.position = (d, 0.0, 0.0)
            self.isolator.vertices = vertices
            self.force_bar.scale = (length, 1.0, 1.0)
            self.force_bar.position = (0.8 + d + math.copysign(length / 2, force_n), -0.9, DRAW["table_z"] + 0.15)
            if push != self._push:
                self._push = push
                self.force_bar.color = (255, 80, 80) if push else (80, 160, 255)
            if self._updates % LABEL_EVERY == 0:
                self.label.text = f"y = {displacement_m * 1000:+.1f} mm   F = {force_n / 1000:+.1f} kN"
            if text is not None:
                self.status.content = text

    def set_text(self, text: str) -> None:
        with self._lock:
            self.status.content = text

    def stop(self) -> None:
        with contextlib.suppress(Exception):
            self.server.stop()
        shutil.rmtree(self.socket_dir, ignore_errors=True)


class ViewerRelay:
    """Starts the scene on first use, feeds it from the live stream while someone watches, relays HTTP + ws."""

    def __init__(self, hub, settings):
        self.hub = hub
        self.settings = settings
        self.scene: RigScene | None = None
        self.watchers = 0
        self.feeder: asyncio.Task | None = None
        self._start_lock = asyncio.Lock()
        self._page_cache: dict[str, tuple[bytes, dict]] = {}

    async def ensure_scene(self) -> RigScene:
        async with self._start_lock:
            if self.scene is None:
                self.scene = await asyncio.to_thread(RigScene)
        return self.scene

    def http_client(self) -> httpx.AsyncClient:
        """A client of viser's HTTP server, over its Unix socket."""
        return httpx.AsyncClient(base_url="http://viewer", timeout=10.0,
                                 transport=httpx.AsyncHTTPTransport(uds=self.scene.socket_path))

    def connect_ws(self, subprotocols: list[str] | None):
        """viser's websocket, over its Unix socket."""
        return websockets.asyncio.client.unix_connect(self.scene.socket_path, "ws://viewer/",
                                                      subprotocols=subprotocols, max_size=None, compression=None,
                                                      open_timeout=10)

    async def feed(self) -> None:
        """Follow the live stream; show the newest sample at most every UPDATE_PERIOD_S."""
        scene = self.scene
        while self.watchers > 0:
            sub = self.hub.subscribe(None)
            if inspect.isawaitable(sub):
                sub = await sub
            last = 0.0
            title = ""
            try:
                async for msg in sub:
                    if self.watchers <= 0:
                        break
                    kind = msg.get("type")
                    if kind == "status":
                        cycle = msg.get("cycle")
                        total = msg.get("cycles_total")
                        text = f"**test #{msg.get('test_id')}**: {msg.get('status', '')}"
                        if cycle is not None and total:
                            text += f", cycle {cycle} / {total}"
                        if text != title:
                            title = text
                            await asyncio.to_thread(scene.set_text, text)
                    elif kind == "samples" and msg.get("rows"):
                        now = time.monotonic()
                        if now - last < UPDATE_PERIOD_S:
                            continue
                        last = now
                        cols = msg["columns"]
                        row = msg["rows"][-1]
                        y = row[cols.index("displacement_m")]
                        f = row[cols.index("force_n")]
                        if y is not None and f is not None:
                            await asyncio.to_thread(scene.show, float(y), float(f))
            except asyncio.CancelledError:
                raise
            except Exception:  # a broken subscription must not kill the view: resubscribe
                log.exception("3D view feed failed; resubscribing")
                await asyncio.sleep(1.0)
            finally:
                close = getattr(sub, "close", None)
                if close is not None:
                    res = close()
                    if inspect.isawaitable(res):
                        await res
            if self.watchers > 0:
                await asyncio.sleep(0.2)

    def watch(self) -> None:
        self.watchers += 1
        if self.feeder is None or self.feeder.done():
            self.feeder = asyncio.get_running_loop().create_task(self.feed())

    def unwatch(self) -> None:
        self.watchers = max(0, self.watchers - 1)
        if self.watchers == 0 and self.feeder is not None:
            self.feeder.cancel()
            self.feeder = None

    def close(self) -> None:
        if self.feeder is not None:
            self.feeder.cancel()
        if self.scene is not None:
            self.scene.stop()
            self.scene = None


def _close_at_shutdown(app, relay: ViewerRelay) -> None:
    """Close the view when the application's lifespan ends (a shutdown handler is never run beside a lifespan)."""
    inner = app.router.lifespan_context

    @contextlib.asynccontextmanager
    async def lifespan(application):
        try:
            async with inner(application) as state:
                yield state
        finally:
            relay.close()

    app.router.lifespan_context = lifespan


def attach(app, hub, settings) -> ViewerRelay | None:
    """Add ``/viewer/status``, the HTTP relay ``/viewer/...`` and the websocket relay ``/viewer`` to ``app``.

    Call before mounting the static site at ``/`` (a mount at ``/`` would shadow these routes).
    """
    enabled = viewer_enabled(settings)

    @app.get("/viewer/status", include_in_schema=False)
    async def viewer_status() -> JSONResponse:
        return JSONResponse({"enabled": enabled, "path": "/viewer/"})

    if not enabled:
        return None
    relay = ViewerRelay(hub, settings)
    app.state.viewer = relay
    _close_at_shutdown(app, relay)

    @app.get("/viewer", include_in_schema=False)
    async def viewer_root() -> RedirectResponse:
        return RedirectResponse("/viewer/")

    @app.get("/viewer/{path:path}", include_in_schema=False)
    async def viewer_http(path: str, request: Request) -> Response:
        if ".." in path.split("/"):
            return JSONResponse({"detail": "not found"}, status_code=404)
        try:
            await relay.ensure_scene()
        except Exception as exc:
            log.exception("the 3D view did not start")
            return JSONResponse({"detail": f"the 3D view could not start: {exc}"}, status_code=503)
        gzip_ok = "gzip" in request.headers.get("accept-encoding", "")
        key = f"{path}|{gzip_ok}"
        if key not in relay._page_cache:
            async with relay.http_client() as client:
                req = client.build_request("GET", f"/{path}",
                                           headers={"Accept-Encoding": "gzip" if gzip_ok else "identity"})
                upstream = await client.send(req, stream=True)
                body = b"".join([chunk async for chunk in upstream.aiter_raw()])
                await upstream.aclose()
            headers = {"Content-Type": upstream.headers.get("content-type", "application/octet-stream"),
                       "Cache-Control": "no-cache"}
            if upstream.headers.get("content-encoding", "identity") != "identity":
                headers["Content-Encoding"] = upstream.headers["content-encoding"]
            if upstream.status_code != 200:
                return Response(body, status_code=upstream.status_code, headers=headers)
            relay._page_cache[key] = (body, headers)
        body, headers = relay._page_cache[key]
        return Response(body, headers=headers)

    async def viewer_ws(websocket: WebSocket) -> None:
        offered = [p.strip() for p in websocket.headers.get("sec-websocket-protocol", "").split(",") if p.strip()]
        try:
            await relay.ensure_scene()
            upstream = await relay.connect_ws(offered or None)
        except Exception:
            log.exception("the 3D view's websocket could not be relayed")
            await websocket.close(code=1011)
            return
        await websocket.accept(subprotocol=upstream.subprotocol)
        relay.watch()

        async def down() -> None:  # viser -> browser
            async for data in upstream:
                if isinstance(data, bytes):
                    await websocket.send_bytes(data)
                else:
                    await websocket.send_text(data)

        async def up() -> None:  # browser -> viser (share requests dropped)
            while True:
                msg = await websocket.receive()
                if msg["type"] == "websocket.disconnect":
                    return
                data = msg.get("bytes")
                if data is not None:
                    if b"ShareUrl" in data:
                        continue
                    await upstream.send(data)
                elif msg.get("text") is not None:
                    await upstream.send(msg["text"])

        tasks = [asyncio.create_task(down()), asyncio.create_task(up())]
        try:
            await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        except WebSocketDisconnect:
            pass
        finally:
            for t in tasks:
                t.cancel()
            with contextlib.suppress(Exception):
                await upstream.close()
            with contextlib.suppress(Exception):
                await websocket.close()
            relay.unwatch()

    app.add_api_websocket_route("/viewer", viewer_ws)
    app.add_api_websocket_route("/viewer/", viewer_ws)
    return relay
