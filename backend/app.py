"""``create_app(settings)``: the FastAPI application with its store, rig service, stream hub and routes.

At creation the service takes its rig's lock (backend.rig_lock: one service per rig name and database; a second
one is refused with ``RigBusy`` before it changes anything), then the database is migrated (Alembic) and any test
of this service's rig left ``running`` by a dead service is marked ``interrupted`` (the lock says its service is
gone; another rig's service may share the database: its tests are left alone). The lock is let go at shutdown.
Accounts (backend.accounts): the first start creates ``admin`` and writes its password to a file of mode 0600 in
the data directory (``first-admin-password.txt``), saying only where on the server's terminal;
``ISORIG_OPERATOR_TOKEN``, where set, is the token of the service account ``automation``. Routes: ``/api/...``
(REST, OpenAPI at ``/docs``), ``/ws/...`` (websocket schema v1), the 3D viewer if ``backend.viewer`` is
installed, and the dashboard's static files at ``/``.
"""

from __future__ import annotations

import asyncio
import logging
import sys
import threading
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles

from . import accounts, db, errors, rig_lock, store
from .api import accounts as accounts_api
from .api import commissioning, ground_motions, isolators, lab, login, meta, motion, protocols, tests, ws
from .auth import LoginThrottle
from .checks import CheckPool, HeavyBodyGate
from .commissioning import Fitter
from .doors import ServiceDoors
from .rig_in_force import rig_in_force
from .service import RigService
from .settings import Settings
from .stream import Hub

log = logging.getLogger("isorig")


def bootstrap_accounts(sessions, service_token: bool, password_file: Path | None = None) -> tuple[str, str] | None:
    """The service account (if a service token is set) and, on the first start, ``admin`` (its name and password
    returned; the password written to ``password_file`` before the account is committed, so an account is never
    made whose password nobody was told). Several rigs' services may start together on one database: one at a
    time (db.startup_lock)."""
    with sessions() as session:
        db.startup_lock(session)
        if service_token:
            accounts.ensure_service_account(session)
        first = accounts.first_admin(session)
        if first is not None and password_file is not None:
            try:
                accounts.write_first_password(password_file, first[1])
            except OSError as exc:  # no account is made whose password nobody could read
                raise RuntimeError(f"cannot write the first admin's password to {password_file} ({exc.strerror}): "
                                   "give a data directory this user can write (--data-dir, ISORIG_DATA_DIR)") from None
        session.commit()
    return first


def _warm_reports(sessions) -> threading.Event:
    """The report renderer and the store's report queries warmed up in a background thread
    (backend.reports.warm: imported there, not here); the event is set when it is done (or could not be)."""
    done = threading.Event()

    def run() -> None:
        try:
            from .reports.warm import freeze_startup_objects, warm_once, warm_store

            warm_once()
            warm_store(sessions)
            freeze_startup_objects()
        except ImportError:  # an installation without reports: nothing to warm
            pass
        except Exception:  # noqa: BLE001 - a failed warm-up costs the first report its time, never the service
            log.warning("the store's report queries could not be warmed up", exc_info=True)
        finally:
            done.set()

    threading.Thread(target=run, daemon=True, name="isorig-report-warm-up").start()
    return done


def create_app(settings: Settings | None = None, driver: str | None = None) -> FastAPI:
    settings = settings or Settings()
    engine = db.make_engine(settings.resolved_database_url)
    lock = rig_lock.take(engine, settings.rig_name, settings.host, settings.port)  # before any write: RigBusy
    try:
        db.upgrade(engine)
        sessions = db.session_factory(engine)
        with sessions() as session:
            interrupted = store.mark_running_interrupted(session, settings.rig_name)  # this rig's, service gone
            session.commit()
    except BaseException:
        lock.release()
        raise
    if interrupted:
        log.warning("tests %s were running when the service stopped: marked interrupted", interrupted)
    service_token = settings.operator_token.get_secret_value() if settings.operator_token else ""
    password_file = settings.data_dir / accounts.FIRST_PASSWORD_FILE
    first = bootstrap_accounts(sessions, bool(service_token), password_file)
    hub = Hub(settings.stream_history_s)
    service = RigService(settings, sessions, hub, driver)
    service.rig_lock = lock
    checks = CheckPool(service.context, settings.check_workers, settings.check_queue,  # heavy token-free work
                       settings.check_worker_max_rss_bytes)
    fitter = Fitter(service, sessions)  # a commissioning's fit, once its run has ended (backend.commissioning)
    service.end_hooks.append(fitter.on_end)

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        hub.bind(asyncio.get_running_loop())
        threading.Thread(target=service.prepare, daemon=True, name="isorig-forkserver-start").start()
        threading.Thread(target=fitter.resume, daemon=True, name="isorig-fit-resume").start()
        if settings.report_warm_up:
            app.state.report_warm = _warm_reports(sessions)
        if first is not None:  # where its password is, on the server's terminal only (never the password itself)
            print(f"isorig: first start: created the account '{first[0]}' (role admin); its password is in "
                  f"{password_file} (mode 0600: only this user reads it)\n        log in at "
                  f"http://{settings.host}:{settings.port}/ as {first[0]} with it, then delete the file; add the "
                  "lab's accounts with `isorig user add NAME --role operator` (`isorig user --help`)",
                  file=sys.stderr, flush=True)
        try:
            yield
        finally:
            checks.shutdown()
            await asyncio.get_running_loop().run_in_executor(None, service.shutdown)
            lock.release()  # once its tests are recorded as ended
            engine.dispose()

    app = FastAPI(title="isorig", version="0.1.0", lifespan=lifespan,
                  description="Control and test service for a hydraulic seismic-isolator test rig. Actions that "
                              "move the rig or change records need an account with the right role: a login session "
                              "(POST /api/session) or an API token (Authorization: Bearer).")
    app.state.settings = settings
    # --rig-file, else the rig file applied from a commissioning (kept across a restart), else the defaults
    app.state.rig_description, app.state.rig_origin = rig_in_force(settings)
    app.state.rig = app.state.rig_description.parameters  # what the controller assumes; envelope, limits
    app.state.fitter = fitter
    app.state.engine = engine
    app.state.rig_lock = lock
    app.state.sessions = sessions
    app.state.service_token = service_token
    app.state.login_throttle = LoginThrottle()
    app.state.hub = hub
    app.state.service = service
    app.state.checks = checks
    app.state.report_warm = None  # the renderer's warm-up (a threading.Event) once the service has started
    errors.install(app)
    # inside the doors: a big body on a token-free heavy route is admitted before it is read (backend.checks)
    app.add_middleware(HeavyBodyGate, pool=checks)
    # Host allow-list, body cap, cross-site refusals, before any route (backend.doors; docs/backend.md)
    app.add_middleware(ServiceDoors, max_body_bytes=settings.max_body_bytes,
                       allowed_hosts=settings.host_allow_list())
    app.include_router(meta.router)
    app.include_router(login.router)
    app.include_router(accounts_api.router)
    app.include_router(lab.router)
    app.include_router(isolators.router)
    app.include_router(tests.router)
    app.include_router(protocols.router)
    app.include_router(ground_motions.router)
    app.include_router(motion.router)
    app.include_router(commissioning.router)
    app.include_router(ws.router)
    try:
        from . import viewer
    except ImportError:
        viewer = None
    if viewer is not None and hasattr(viewer, "attach"):
        viewer.attach(app, hub, settings)
    if settings.static_dir.is_dir():
        app.mount("/", StaticFiles(directory=settings.static_dir, html=True), name="frontend")
    return app
