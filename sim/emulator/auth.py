"""The rig link's authentication (docs/rig-protocol.md, protocol version 2): the lab's key file, the
HMAC-SHA-256 tags, the per-session key, and the policy that decides whether a link may run without a key.

Standard library only (hmac, hashlib, secrets): a lab's real-time target in C implements the same from the
document. Nothing here is a new primitive: a tag is HMAC-SHA-256 truncated to ``TAG_BYTES``, compared in
constant time (``hmac.compare_digest``).
"""

from __future__ import annotations

import hashlib
import hmac
import ipaddress
import os
import secrets
import socket
import stat
from dataclasses import dataclass
from pathlib import Path

KEY_MIN_BYTES = 32  # 256 bits
KEY_MAX_BYTES = 1024
TAG_BYTES = 16  # HMAC-SHA-256 truncated to its first 16 bytes (128 bits)
NONCE_BYTES = 16
SESSION_LABEL = b"isorig rig v2 session"
KEY_FILE_ENV = "ISORIG_RIG_KEY_FILE"
PROTOCOL_ENV = "ISORIG_RIG_PROTOCOL"


class KeyFileError(ValueError):
    """A key file that cannot be used: the message says what is wrong and what is allowed."""


def tag(key: bytes, data: bytes) -> bytes:
    """The first TAG_BYTES of HMAC-SHA-256(key, data)."""
    return hmac.new(key, data, hashlib.sha256).digest()[:TAG_BYTES]


def tag_ok(key: bytes, data: bytes, received: bytes) -> bool:
    """Whether ``received`` is the tag of ``data`` under ``key`` (constant-time compare)."""
    return hmac.compare_digest(tag(key, data), received)


def session_key(lab_key: bytes, challenge: bytes, session: int) -> bytes:
    """The key of one armed session: HMAC-SHA-256(lab key, label | the rig's challenge | session u32 LE)."""
    return hmac.new(lab_key, SESSION_LABEL + challenge + (session & 0xFFFFFFFF).to_bytes(4, "little"),
                    hashlib.sha256).digest()


def new_nonce() -> bytes:
    return secrets.token_bytes(NONCE_BYTES)


# --- the key file ---------------------------------------------------------------------------------------------
ALLOWED = (f"a key file holds at least {KEY_MIN_BYTES} bytes ({KEY_MIN_BYTES * 8} bits): either "
           f"{2 * KEY_MIN_BYTES}+ hex digits on one line, or {KEY_MIN_BYTES}+ raw bytes; readable by its owner only "
           "(chmod 600); make one with `isorig rig-key new FILE`")


def parse_key(data: bytes, name: str = "key") -> bytes:
    """The key in a key file's bytes: hex text (only hex digits and white space) or else raw bytes."""
    text = data.strip()
    if text and all(c in b"0123456789abcdefABCDEF \t\r\n" for c in text):
        digits = bytes(c for c in text if c not in b" \t\r\n")
        if len(digits) % 2:
            raise KeyFileError(f"{name}: {len(digits)} hex digits is an odd number (a digit missing or extra?); "
                               f"{ALLOWED}")
        key = bytes.fromhex(digits.decode("ascii"))
    else:
        key = data
    if len(key) < KEY_MIN_BYTES:
        raise KeyFileError(f"{name}: {len(key)} bytes of key is too short; {ALLOWED}")
    if len(key) > KEY_MAX_BYTES:
        raise KeyFileError(f"{name}: {len(key)} bytes is not a key (at most {KEY_MAX_BYTES}); {ALLOWED}")
    return key


def load_key_file(path: str | os.PathLike) -> bytes:
    """The lab's key from ``path``, or a KeyFileError that says what is wrong and what is allowed."""
    path = Path(path)
    try:
        info = path.stat()
    except OSError as exc:
        raise KeyFileError(f"rig key file {str(path)!r}: {exc.strerror or exc}; {ALLOWED}") from None
    if not stat.S_ISREG(info.st_mode):
        raise KeyFileError(f"rig key file {str(path)!r} is not a regular file; {ALLOWED}")
    if info.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise KeyFileError(f"rig key file {str(path)!r} is accessible by its group or others (mode "
                           f"{stat.S_IMODE(info.st_mode):04o}); run `chmod 600 {path}`: {ALLOWED}")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise KeyFileError(f"rig key file {str(path)!r}: {exc.strerror or exc}; {ALLOWED}") from None
    return parse_key(data, f"rig key file {str(path)!r}")


def write_key_file(path: str | os.PathLike, n_bytes: int = KEY_MIN_BYTES) -> Path:
    """A new random key as hex in a new file of mode 0600 (never over an existing file)."""
    path = Path(path)
    if n_bytes < KEY_MIN_BYTES:
        raise KeyFileError(f"a key of {n_bytes} bytes is too short; {ALLOWED}")
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        raise KeyFileError(f"{str(path)!r} exists: a key file is never overwritten (the rig and the host must "
                           "hold the same key); remove it first or choose another name") from None
    except OSError as exc:
        raise KeyFileError(f"cannot create {str(path)!r}: {exc.strerror or exc}") from None
    with os.fdopen(fd, "w") as f:
        os.fchmod(f.fileno(), 0o600)  # whatever the umask
        f.write(secrets.token_hex(n_bytes) + "\n")
    return path


# --- the policy: which protocol, with which key ------------------------------------------------------------------
@dataclass(frozen=True)
class LinkSecurity:
    """How one link is protected: protocol version 2 with the lab's key, or version 1 without any."""

    protocol_version: int
    key: bytes | None = None
    key_file: str | None = None
    why: str = ""  # why this link runs without a key (version 1), for the start line and the record

    @property
    def authenticated(self) -> bool:
        return self.key is not None

    def describe(self) -> dict:
        out = {"protocol_version": self.protocol_version, "authenticated": self.authenticated}
        if self.key_file:
            out["key_file"] = self.key_file
        if not self.authenticated:
            out["unauthenticated_because"] = self.why
        return out


def is_loopback(host: str) -> bool:
    """Whether every address ``host`` names is a loopback address (127.0.0.0/8, ::1)."""
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        pass
    try:
        infos = socket.getaddrinfo(host, None)
    except OSError:
        return False
    return bool(infos) and all(ipaddress.ip_address(info[4][0]).is_loopback for info in infos)


def resolve_security(host: str, key_file: str | os.PathLike | None = None, protocol_version: int | str | None = None,
                     env: dict | None = None) -> LinkSecurity:
    """The link's protection from ``--rig-key-file`` / ``--rig-protocol`` (else ``ISORIG_RIG_KEY_FILE`` /
    ``ISORIG_RIG_PROTOCOL``): version 2 with a key; version 1 (no key) only when named, or on loopback when no
    key is given. A ValueError (KeyFileError) that says what to do otherwise."""
    env = os.environ if env is None else env
    if key_file in (None, ""):
        key_file = env.get(KEY_FILE_ENV) or None
    if protocol_version in (None, ""):
        protocol_version = env.get(PROTOCOL_ENV) or None
    if protocol_version is not None:
        try:
            protocol_version = int(protocol_version)
        except (TypeError, ValueError):
            protocol_version = -1
        if protocol_version not in (1, 2):
            raise ValueError("rig protocol must be 1 (unauthenticated, for a lab's existing v1 target) or 2 "
                             "(authenticated with --rig-key-file, the default)")
    if protocol_version == 1:
        if key_file is not None:
            raise ValueError("rig protocol 1 has no authentication: give either --rig-key-file (protocol 2) or "
                             "--rig-protocol 1, not both")
        return LinkSecurity(1, why="rig protocol 1 named (--rig-protocol 1 / ISORIG_RIG_PROTOCOL=1)")
    if key_file is not None:
        return LinkSecurity(2, load_key_file(key_file), str(key_file))
    if protocol_version == 2:
        raise ValueError(f"rig protocol 2 needs the lab's key: --rig-key-file FILE (or {KEY_FILE_ENV}); make one "
                         "with `isorig rig-key new FILE` and give the same file to the rig")
    if is_loopback(host):
        return LinkSecurity(1, why="loopback without a key file (any process on this machine can reach it)")
    raise ValueError(f"the rig link to {host} needs the lab's key: --rig-key-file FILE (or {KEY_FILE_ENV}; make one "
                     "with `isorig rig-key new FILE` and give the same file to the rig); to run the "
                     "unauthenticated protocol 1 anyway (a lab's bring-up, an existing v1 target), name it: "
                     f"--rig-protocol 1 (or {PROTOCOL_ENV}=1)")
