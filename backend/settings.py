"""Service settings in one place (pydantic settings; environment variables prefixed ``ISORIG_``)."""

from __future__ import annotations

import re
from pathlib import Path

import platformdirs
from pydantic import Field, SecretStr, field_validator, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

REPO_STATIC_DIR = Path(__file__).resolve().parent.parent / "frontend" / "static"

# a simulated test's (and commissioning's) speed factor: at most 10 times slower than real time, and no faster than
# this however ISORIG_MAX_SPEED is set (1e-300 overflowed the worker's clock; below 0.1 a 4 h test takes weeks)
MIN_SPEED = 0.1
MAX_SPEED_LIMIT = 1000.0

DEFAULT_RIG_NAME = "rig-1"  # the one rig of a lab's database before rigs were named (migration 0007)
RIG_NAME_RULE = "1-64 characters: letters, digits, '-', '_' and '.'"
_RIG_NAME = re.compile(r"[A-Za-z0-9._-]{1,64}")


def check_rig_name(value: str) -> str:
    """The rig's name as given, or ValueError saying what is allowed (``RIG_NAME_RULE``)."""
    if not isinstance(value, str) or not _RIG_NAME.fullmatch(value):
        raise ValueError(f"the rig name {value!r} is not allowed: {RIG_NAME_RULE}")
    return value


class Settings(BaseSettings):
    """Everything the service can be told; every field can be set as ``ISORIG_<NAME>``."""

    model_config = SettingsConfigDict(env_prefix="ISORIG_", extra="ignore")

    data_dir: Path = Field(default_factory=lambda: Path(platformdirs.user_data_dir("isorig")),
                           description="where the SQLite database lives")
    database_url: str | None = Field(default=None, description="any SQLAlchemy URL; default SQLite in data_dir")
    operator_token: SecretStr | None = Field(default=None, description="the API token of the service account "
                                             "'automation' (role operator), for a lab's automation; unset: no "
                                             "such account acts (people log in, scripts use `isorig user token`)")
    host: str = "127.0.0.1"
    port: int = 8000
    allowed_hosts: str = Field(default="", max_length=2000, description="more names the service answers to in the "
                               "Host header (DNS rebinding guard), separated by commas or spaces, beyond localhost, "
                               "127.0.0.1, [::1] and the address it binds (`--allowed-host`, repeatable); '*' "
                               "answers to any name (no guard: only behind a proxy that checks Host)")
    forwarded_allow_ips: str = Field(default="", max_length=2000, description="the reverse proxies whose "
                                     "X-Forwarded-For and X-Forwarded-Proto are believed (addresses or networks, "
                                     "e.g. '127.0.0.1' or '10.0.0.0/8', separated by commas or spaces; "
                                     "`--forwarded-allow-ips`); empty (default): none, every request's address is "
                                     "the one it came from, as the login throttle and the audit trail see it")
    max_body_bytes: int = Field(default=16 * 1024 * 1024, ge=64 * 1024, le=1024**3, description="largest request "
                                "body accepted, bytes (413 before it is read); the largest legitimate one, a "
                                "200 000-sample inline history, is 6.3 MB as JSON (10 MB if every number had 17 "
                                "digits); an .AT2 file is at most 12 MB (scripts/bench_doors.py)")
    check_workers: int = Field(default=1, ge=1, le=8, description="processes that build history and hybrid "
                               "profiles and read .AT2 files for requests without the token (/api/tests/check, "
                               "/api/ground-motions/read-at2), apart from the service's own")
    check_worker_max_rss_bytes: int = Field(default=512 * 1024**2, ge=64 * 1024**2, description="a check worker "
                                            "still larger than this after a job (its garbage returned) is retired, "
                                            "bytes: its memory goes with it")
    check_queue: int = Field(default=1, ge=0, le=16, description="such requests that may wait for a worker; "
                             "beyond workers + queue the answer is 503 with Retry-After")
    abort_wait_s: float = Field(default=5.0, ge=0.0, le=60.0, description="POST .../abort answers once the test "
                                "has ended, waiting at most this long (else 202 with the record's URL)")
    static_dir: Path = REPO_STATIC_DIR
    max_test_duration_s: float = Field(default=4 * 3600.0, gt=0, le=7 * 24 * 3600.0,
                                       description="longest test the API accepts, s (at most a week)")
    report_warm_up: bool = Field(default=True, description="warm the report renderer up in the background when "
                                 "the service starts (imports, numba kernels, fonts: about 2 s of one CPU), so that "
                                 "the first report takes no longer than the next ones")
    max_speed: float = Field(default=100.0, ge=1.0, le=MAX_SPEED_LIMIT, description="largest speed factor of a "
                             f"simulated test (1 to {MAX_SPEED_LIMIT:g}; the smallest is {MIN_SPEED:g})")
    stream_history_s: float = Field(default=10.0, description="simulated seconds of samples a late client gets")
    worker_start_method: str = Field(default="forkserver", description="multiprocessing start method: forkserver "
                                     "or spawn (never fork from the threaded server)")
    worker_realtime: bool = Field(default=True, description="ask for real-time scheduling of the rig worker "
                                  "(SCHED_RR if permitted, else nice -10, else normal; and a 0.1 ms time slice, "
                                  "which needs no privilege: sim.realtime.short_slice)")
    service_nice: int = Field(default=0, description="nice increment `isorig serve` applies to itself at start "
                              "(e.g. -10 on a shared machine: steadier streaming; needs root or CAP_SYS_NICE)")
    ws_per_message_deflate: bool = Field(default=False, description="compress websocket messages (saves "
                                         "bandwidth on slow links, costs server CPU per client)")
    viewer: bool = Field(default=True, description="serve the 3D view under /viewer/ (backend.viewer)")
    commit_interval_s: float = Field(default=0.5, description="samples are committed at least this often (wall)")
    rig_name: str = Field(default=DEFAULT_RIG_NAME, description="the name of the rig this service drives "
                          f"({RIG_NAME_RULE}; `--rig-name`): every record it makes carries it, it starts only its "
                          "rig's tests, and several services (one per rig) can share one database")
    rig: str = Field(default="simulated", description="the rig tests run on: 'simulated' or 'udp://HOST:PORT' (a "
                     "real-time I/O target or `isorig rig-emulator`, docs/rig-protocol.md)")
    rig_period_s: float = Field(default=0.001, gt=0, description="control period the UDP rig must run at")
    rig_link_timeout_s: float = Field(default=0.05, gt=0, le=5.0, description="UDP rig: a link silent this long "
                                      "ends the test 'failed' (the rig's watchdog closes its valve by itself)")
    rig_key_file: Path | None = Field(default=None, description="UDP rig: the lab's key file (rig protocol 2: "
                                      "every packet authenticated; `isorig rig-key new FILE` makes one)")
    rig_protocol: int | None = Field(default=None, description="UDP rig: 2 (default; needs rig_key_file) or 1 "
                                     "(unauthenticated, named for a lab's bring-up or an existing v1 target); without "
                                     "a key only a rig on loopback runs, unauthenticated, unless 1 is named")
    rig_arm_timeout_s: float = Field(default=2.0, gt=0, le=60.0, description="UDP rig: how long arming may take")
    rig_start_tolerance_m: float = Field(default=0.002, gt=0, le=0.05, description="UDP rig: a test starts only "
                                         "with the table this close to zero (m), where every test's target begins")
    rig_file: Path | None = Field(default=None, description="the lab's rig: a .json or .toml file of RigParameters "
                                  "names (SI) over the defaults (docs/compare.md, 'Rig files'); what the controller "
                                  "assumes, the envelope and the limits follow it")
    plant_set: str = Field(default="", description="simulated rig only: the rig as it truly is, unlike the rig file "
                           "(NAME=VALUE of rig or isolator parameters, SI, separated by commas or spaces; "
                           "`--plant-set`, repeatable): every job's scenario.plant_changes, shown in GET /api/rig")
    lab_name: str = Field(default="", max_length=200, description="the lab named at the top of every report")
    lab_address: str = Field(default="", max_length=500, description="the lab's address under its name in reports "
                             "(lines separated by newlines or ';')")
    lab_logo_file: Path | None = Field(default=None, description="an image (PNG, JPEG) printed beside the lab's name "
                                       "in reports; missing or unreadable: one warning, the report is made without it")

    @field_validator("rig_name")
    @classmethod
    def _rig_name(cls, value: str) -> str:
        return check_rig_name(value)

    @field_validator("forwarded_allow_ips")
    @classmethod
    def _proxy_addresses(cls, value: str) -> str:
        """The trusted proxies as uvicorn takes them (comma-separated), each an IP address or network."""
        import ipaddress

        items = []
        for item in value.replace(",", " ").split():
            try:  # as uvicorn compares them: an address, or a network written with its host bits zero
                items.append(str(ipaddress.ip_network(item, strict=False) if "/" in item
                                 else ipaddress.ip_address(item)))
            except ValueError:
                raise ValueError(f"{item!r} is not an IP address or network (a trusted proxy is named by its "
                                 "address, e.g. 127.0.0.1, ::1 or 10.0.0.0/8; '*' is not taken)") from None
        return ",".join(items)

    def proxy_options(self) -> dict:
        """uvicorn's proxy options: forwarded headers believed only from the proxies named, none by default
        (uvicorn's own default believes them from 127.0.0.1, so that anyone on the machine could forge an
        address)."""
        if not self.forwarded_allow_ips:
            return {"proxy_headers": False, "forwarded_allow_ips": ""}
        return {"proxy_headers": True, "forwarded_allow_ips": self.forwarded_allow_ips}

    @field_validator("rig")
    @classmethod
    def _known_rig(cls, value: str) -> str:
        from .drivers import rig_kind

        rig_kind(value)  # ValueError with what is allowed
        return value

    @field_validator("rig_file")
    @classmethod
    def _readable_rig_file(cls, value: Path | None) -> Path | None:
        if value is not None:
            from sim.rigfile import load_rig_file

            load_rig_file(value)  # RigError (a ValueError) says what is wrong with the file
        return value

    @field_validator("plant_set")
    @classmethod
    def _plant_assignments(cls, value: str) -> str:
        plant_changes_of(value)  # FieldError (a ValueError) names the parameter and what is allowed
        return value

    @model_validator(mode="after")
    def _rig_link_security(self):
        if self.rig.startswith("udp://"):
            self.rig_security()  # ValueError: a key file that cannot be used, or a link that needs one
        return self

    def rig_security(self, rig: str | None = None):
        """How the UDP rig's link (to ``rig``, default the service's) is protected (sim.emulator.auth)."""
        from sim.emulator.auth import resolve_security

        from .drivers.udp import parse_udp_url

        host, _ = parse_udp_url(rig or self.rig)
        return resolve_security(host, self.rig_key_file, self.rig_protocol, env={})

    def rig_security_options(self) -> dict:
        """The key file and protocol version that ``probe`` and the UDP driver are given."""
        return {"key_file": str(self.rig_key_file) if self.rig_key_file else None,
                "protocol_version": self.rig_protocol}

    @model_validator(mode="after")
    def _plant_only_simulated(self):
        if self.plant_set.strip() and self.rig != "simulated":
            raise ValueError(f"plant_set changes the simulated rig only; the rig {self.rig} is as it is (leave "
                             "--plant-set / ISORIG_PLANT_SET out)")
        return self

    def plant_changes(self) -> dict:
        """The simulated rig's plant changes (name -> SI value), {} when the plant is its rig file's rig."""
        return plant_changes_of(self.plant_set)

    def rig_description(self):
        """The rig the service drives (sim.rigfile.RigDescription): the rig file's, else the defaults."""
        from sim.rig import DEFAULT_RIG
        from sim.rigfile import RigDescription, load_rig_file

        return RigDescription(DEFAULT_RIG) if self.rig_file is None else load_rig_file(self.rig_file)

    def link_settings(self) -> dict:
        """What the worker's UDP driver is built with (host and port come from ``rig``)."""
        return {"period_s": self.rig_period_s, "timeout_s": self.rig_link_timeout_s,
                "arm_timeout_s": self.rig_arm_timeout_s, **self.rig_security_options()}

    def host_allow_list(self) -> list[str]:
        """The names the Host header may carry: the loopback names, the bound address unless a wildcard, and
        ``allowed_hosts``."""
        names = ["localhost", "127.0.0.1", "::1"]
        if self.host not in ("0.0.0.0", "::", ""):
            names.append(self.host.strip("[]"))
        names += [n.strip("[]") for n in self.allowed_hosts.replace(",", " ").split()]
        return list(dict.fromkeys(n.lower() for n in names))

    @property
    def resolved_database_url(self) -> str:
        if self.database_url:
            return self.database_url
        return f"sqlite:///{self.data_dir / 'isorig.db'}"



def plant_changes_of(text: str) -> dict:
    """``NAME=VALUE`` assignments separated by commas or white space -> {name: value}; each name a rig or
    isolator parameter (sim.rigfile.parse_assignment), the rig ones within the rig's ranges."""
    from sim.engine import ISOLATOR_PARAMETERS
    from sim.rig import DEFAULT_RIG
    from sim.rigfile import RIG_FIELDS, parse_assignment, rig_from_mapping

    changes = dict(parse_assignment(a, RIG_FIELDS + ISOLATOR_PARAMETERS, "rig or isolator parameter")
                   for a in text.replace(",", " ").split())
    rig_from_mapping({k: v for k, v in changes.items() if k in RIG_FIELDS}, DEFAULT_RIG, "plant_set")
    return changes
