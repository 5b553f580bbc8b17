"""`isorig serve`: the backend service (REST, websockets, dashboard) with uvicorn on the embedded defaults."""

from __future__ import annotations

import os
import sys


def register(sub) -> None:
    p = sub.add_parser("serve", help="run the service: REST API, websockets, dashboard (simulated or UDP rig)")
    p.add_argument("--host", default=None, help="interface to listen on (default 127.0.0.1; ISORIG_HOST)")
    p.add_argument("--port", type=int, default=None, help="TCP port (default 8000; ISORIG_PORT)")
    p.add_argument("--database-url", default=None,
                   help="SQLAlchemy URL (default: SQLite in the user data directory; ISORIG_DATABASE_URL)")
    p.add_argument("--data-dir", default=None, help="data directory for the SQLite file and the token file")
    p.add_argument("--rig-name", default=None, metavar="NAME",
                   help="the name of the rig this service drives (default rig-1; ISORIG_RIG_NAME): 1-64 letters, "
                        "digits, '-', '_', '.'; several services, one per rig, can share one database "
                        "(--database-url): each starts only its rig's tests, History shows every rig's")
    p.add_argument("--rig", default=None, help="the rig: 'simulated' (default) or udp://HOST:PORT, a real-time I/O "
                   "target or `isorig rig-emulator` (ISORIG_RIG; link settings ISORIG_RIG_*, docs/backend.md)")
    p.add_argument("--rig-file", default=None, metavar="FILE",
                   help="the lab's rig: a .json or .toml file of RigParameters names (SI) over the defaults; what "
                        "the controller assumes, the envelope and the limits follow it (ISORIG_RIG_FILE)")
    p.add_argument("--plant-set", action="append", default=[], metavar="NAME=VALUE",
                   help="simulated rig only: the rig as it truly is, unlike its rig file (a rig or isolator "
                        "parameter, SI; repeatable; ISORIG_PLANT_SET): for demos and tests of commissioning")
    from .rig_key import add_link_flags

    add_link_flags(p)  # --rig-key-file, --rig-protocol: as every rig command
    p.add_argument("--allowed-host", action="append", default=[], metavar="NAME",
                   help="a name the service is reached by, beyond localhost, 127.0.0.1, [::1] and --host (the Host "
                        "header is checked against DNS rebinding; repeatable; ISORIG_ALLOWED_HOSTS)")
    p.add_argument("--forwarded-allow-ips", default=None, metavar="IPS",
                   help="the reverse proxies whose X-Forwarded-For / X-Forwarded-Proto are believed: addresses or "
                        "networks, comma-separated (e.g. 127.0.0.1); default none: a request's address is the one "
                        "it came from (ISORIG_FORWARDED_ALLOW_IPS; docs/backend.md, 'Behind a reverse proxy')")
    p.add_argument("--max-body-bytes", type=int, default=None, metavar="BYTES",
                   help="largest request body accepted, bytes (default 16 MiB; 413 beyond; ISORIG_MAX_BODY_BYTES)")
    p.add_argument("--log-level", default="info", choices=("critical", "error", "warning", "info", "debug"))
    p.set_defaults(func=run)


def _masked(url: str) -> str:
    """The URL without its password."""
    from sqlalchemy.engine import make_url

    try:
        return make_url(url).render_as_string(hide_password=True)
    except Exception:
        return "<unparsable URL>"


def cheap_hash_warning(environ) -> str | None:
    """The line a service prints when the test suite's cheap password hashes are switched on (backend.accounts),
    or None: a lab's service must not run with them, and must not do so silently."""
    from backend.accounts import TEST_CHEAP_HASHES_ENV

    if environ.get(TEST_CHEAP_HASHES_ENV, "") == "":
        return None
    return (f"isorig serve: WARNING: {TEST_CHEAP_HASHES_ENV}={environ[TEST_CHEAP_HASHES_ENV]} is set: passwords are "
            "hashed as cheaply as the test suite does (one pass over 8 KiB); unset it for a lab's service")


def run(args) -> int:
    import uvicorn
    from pydantic import ValidationError

    from backend.app import create_app
    from backend.settings import Settings
    from isorig.cli import UsageError

    overrides = {k: v for k, v in (("host", args.host), ("port", args.port), ("database_url", args.database_url),
                                   ("data_dir", args.data_dir), ("rig_name", args.rig_name), ("rig", args.rig),
                                   ("rig_file", args.rig_file),
                                   ("rig_key_file", args.rig_key_file), ("rig_protocol", args.rig_protocol),
                                   ("max_body_bytes", args.max_body_bytes),
                                   ("forwarded_allow_ips", args.forwarded_allow_ips))
                 if v is not None}
    if args.allowed_host:  # as every flag: in place of the environment's ISORIG_ALLOWED_HOSTS
        overrides["allowed_hosts"] = " ".join(args.allowed_host)
    if args.plant_set:
        overrides["plant_set"] = " ".join(args.plant_set)
    try:
        settings = Settings(**overrides)
    except ValidationError as exc:
        first = exc.errors()[0]
        field = ".".join(str(p) for p in first["loc"]) or "settings"
        raise UsageError(f"isorig serve: {field}: {first['msg'].removeprefix('Value error, ')}") from None
    if not (0 < settings.port < 65536):
        raise UsageError(f"isorig serve: --port {settings.port} is outside 1-65535")
    if settings.service_nice:
        try:
            os.nice(settings.service_nice)  # before any thread or worker exists: they all inherit it
        except OSError as exc:
            print(f"isorig serve: ISORIG_SERVICE_NICE={settings.service_nice} not applied ({exc.strerror})",
                  file=sys.stderr)
    from backend.db import DatabaseFileError
    from backend.rig_lock import RigBusy

    try:
        app = create_app(settings)
    except RigBusy as exc:  # another service drives this rig on this database: named, nothing changed
        print(f"isorig serve: {exc}", file=sys.stderr)
        return 3
    except DatabaseFileError as exc:  # an empty file, or one that is not a database: its path, nothing written
        print(f"isorig serve: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # bad URL, unreachable database: one clear line
        print(f"isorig serve: cannot open the database {_masked(settings.resolved_database_url)!r}: "
              f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}", file=sys.stderr)
        return 2
    print(f"isorig: serving on http://{settings.host}:{settings.port}/ (API docs at /docs), "
          f"database {app.state.engine.url.render_as_string(hide_password=True)}, rig {settings.rig_name!r}: "
          f"{settings.rig} "
          f"({app.state.rig_description.name})"
          + (f", the simulated plant unlike it: {settings.plant_set}" if settings.plant_set.strip() else "")
          + (f", forwarded headers believed from {settings.forwarded_allow_ips}" if settings.forwarded_allow_ips
             else ""),
          file=sys.stderr, flush=True)
    warning = cheap_hash_warning(os.environ)
    if warning:
        print(warning, file=sys.stderr, flush=True)
    uvicorn.run(app, host=settings.host, port=settings.port, log_level=args.log_level,
                ws_per_message_deflate=settings.ws_per_message_deflate, **settings.proxy_options())
    return 0
