"""The isorig rig protocol, versions 1 and 2: one UDP datagram per control period each way (docs/rig-protocol.md).

Version 2 (``Codec(2)``) has the same header and the same MEASUREMENT and COMMAND payloads; it ends every
packet with a 16-byte HMAC-SHA-256 tag (sim.emulator.auth) instead of the CRC-32, adds a nonce to HELLO and
the rig's challenge to ARM, and answers a HELLO with an ANSWER (kind 6: a measurement, the HELLO's nonce and
the rig's challenge). What follows describes version 1, the module-level ``encode``/``decode``.

Every packet is little-endian: a 24-byte header, a payload that depends on the kind, and a CRC-32
(zlib's, the one of Ethernet and PNG) of everything before it.

    header   magic b"ISRG" | version u16 | kind u16 | session u32 | sequence u32 | time_ns u64
    MEASUREMENT (rig -> host), sequence = the rig's period since ARM
             position_m f64 | force_n f64 | load_pressure_pa f64 | supply_pressure_pa f64 |
             status u32 | commands_missed u32 | packets_rejected u32 | command_sequence u32 |
             command_latency_us u32 | period_ns u32
    COMMAND  (host -> rig), sequence = the measurement it answers
             command_v f64
    ARM      (host -> rig) supply_pressure_pa f64 | vertical_load_n f64     session = the host's new id (not 0)
    DISARM   (host -> rig) no payload
    HELLO    (host -> rig) no payload: the rig answers with one MEASUREMENT (how the service probes the link)
    trailer  crc32 u32

``session`` ties a packet to one armed test: the host picks a random non-zero id at ARM, the rig echoes it
and drops commands of any other session (a rig that restarted knows none). ``time_ns`` is the sender's
monotonic clock. Nothing here depends on the rest of isorig: a lab's real-time target can implement it
from docs/rig-protocol.md alone.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

from . import auth

MAGIC = b"ISRG"
VERSION = 1
MEASUREMENT, COMMAND, ARM, DISARM, HELLO, ANSWER = 1, 2, 3, 4, 5, 6
KIND_NAMES = {MEASUREMENT: "measurement", COMMAND: "command", ARM: "arm", DISARM: "disarm", HELLO: "hello",
              ANSWER: "answer"}

HEADER = struct.Struct("<4sHHIIQ")
PAYLOADS = {
    MEASUREMENT: struct.Struct("<ddddIIIIII"),
    COMMAND: struct.Struct("<d"),
    ARM: struct.Struct("<dd"),
    DISARM: struct.Struct("<"),
    HELLO: struct.Struct("<"),
}
CRC = struct.Struct("<I")
SIZES = {kind: HEADER.size + payload.size + CRC.size for kind, payload in PAYLOADS.items()}
MAX_PACKET = max(SIZES.values())
U32 = 0xFFFFFFFF


class PacketError(ValueError):
    """A datagram that is not a valid packet of this version; ``reason`` is one word for the counters."""

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


@dataclass(frozen=True)
class Packet:
    """One decoded packet: the header fields and the payload's fields by name."""

    kind: int
    session: int
    sequence: int
    time_ns: int
    fields: dict


MEASUREMENT_FIELDS = ("position_m", "force_n", "load_pressure_pa", "supply_pressure_pa", "status",
                      "commands_missed", "packets_rejected", "command_sequence", "command_latency_us", "period_ns")
PAYLOAD_FIELDS = {MEASUREMENT: MEASUREMENT_FIELDS, COMMAND: ("command_v",),
                  ARM: ("supply_pressure_pa", "vertical_load_n"),
                  DISARM: (), HELLO: ()}


def encode(kind: int, session: int, sequence: int, time_ns: int, *payload) -> bytes:
    """A packet of ``kind`` with its payload values in the order of ``PAYLOAD_FIELDS[kind]``."""
    body = HEADER.pack(MAGIC, VERSION, kind, session & U32, sequence & U32, time_ns & 0xFFFFFFFFFFFFFFFF)
    body += PAYLOADS[kind].pack(*payload)
    return body + CRC.pack(zlib.crc32(body))


def decode(data: bytes) -> Packet:
    """The packet in ``data``, or ``PacketError`` (reason: short, magic, version, kind, size, crc)."""
    if len(data) < HEADER.size + CRC.size:
        raise PacketError("short", f"{len(data)} bytes is shorter than any packet")
    magic, version, kind, session, sequence, time_ns = HEADER.unpack_from(data)
    if magic != MAGIC:
        raise PacketError("magic", f"magic {magic!r} is not {MAGIC!r}")
    if version != VERSION:
        raise PacketError("version", f"protocol version {version}; this side speaks version {VERSION}")
    if kind not in PAYLOADS:
        raise PacketError("kind", f"unknown packet kind {kind}")
    if len(data) != SIZES[kind]:
        raise PacketError("size", f"a {KIND_NAMES[kind]} packet has {SIZES[kind]} bytes, not {len(data)}")
    (crc,) = CRC.unpack_from(data, len(data) - CRC.size)
    if crc != zlib.crc32(data[: len(data) - CRC.size]):
        raise PacketError("crc", "CRC mismatch: the packet was damaged")
    values = PAYLOADS[kind].unpack_from(data, HEADER.size)
    return Packet(kind, session, sequence, time_ns, dict(zip(PAYLOAD_FIELDS[kind], values, strict=True)))


# --- version 2 ----------------------------------------------------------------------------------------------
V2_PAYLOADS = {
    MEASUREMENT: PAYLOADS[MEASUREMENT],
    COMMAND: PAYLOADS[COMMAND],
    ARM: struct.Struct("<dd16s"),
    DISARM: PAYLOADS[DISARM],
    HELLO: struct.Struct("<16s"),
    ANSWER: struct.Struct("<ddddIIIIII16s16s"),
}
V2_FIELDS = {**PAYLOAD_FIELDS, ARM: ("supply_pressure_pa", "vertical_load_n", "challenge"), HELLO: ("nonce",),
             ANSWER: MEASUREMENT_FIELDS + ("nonce", "challenge")}
V2_SIZES = {kind: HEADER.size + payload.size + auth.TAG_BYTES for kind, payload in V2_PAYLOADS.items()}
#: the key a version 2 packet is tagged with: the lab's key, or the key of its session (auth.session_key)
LAB_KEY_KINDS = frozenset({ARM, HELLO, ANSWER})
RIG_RECEIVES = frozenset({COMMAND, ARM, DISARM, HELLO})


@dataclass(frozen=True)
class Header:
    kind: int
    session: int
    sequence: int
    time_ns: int


class Codec:
    """Encode and decode one protocol version. Version 1: CRC-32, no key. Version 2: every packet tagged with
    ``key`` (the lab's key for ARM, HELLO and ANSWER; the session's key for MEASUREMENT, COMMAND, DISARM).

    ``peek`` does the structural checks (short, magic, version, kind, size) and reads the header, so that a
    receiver can drop by header (rate, session, address) and choose the key before ``open`` checks the CRC or
    the tag (reason ``crc`` or ``auth``) and reads the payload."""

    def __init__(self, version: int = VERSION):
        if version not in (1, 2):
            raise ValueError(f"rig protocol version {version!r}; isorig speaks 1 and 2")
        self.version = version
        self.payloads = PAYLOADS if version == 1 else V2_PAYLOADS
        self.fields = PAYLOAD_FIELDS if version == 1 else V2_FIELDS
        self.sizes = SIZES if version == 1 else V2_SIZES
        self.trailer = CRC.size if version == 1 else auth.TAG_BYTES
        self.max_packet = max(self.sizes.values())

    def encode(self, kind: int, session: int, sequence: int, time_ns: int, *payload, key: bytes | None = None) -> bytes:
        body = HEADER.pack(MAGIC, self.version, kind, session & U32, sequence & U32, time_ns & 0xFFFFFFFFFFFFFFFF)
        body += self.payloads[kind].pack(*payload)
        return self.seal(body, key)

    def seal(self, body: bytes, key: bytes | None = None) -> bytes:
        """``body`` (header and payload) with its trailer: the CRC-32 (version 1) or the tag under ``key``."""
        if self.version == 1:
            return body + CRC.pack(zlib.crc32(body))
        if key is None:
            raise ValueError("a version 2 packet needs a key")
        return body + auth.tag(key, body)

    def peek(self, data: bytes, receives: frozenset | None = None) -> Header:
        """The header of a structurally valid packet, or PacketError (short, magic, version, kind, size); a
        kind not in ``receives`` (what this side receives) is dropped as ``kind``."""
        minimum = HEADER.size + self.trailer if self.version == 1 else HEADER.size  # v2: a v1 packet is `version`
        if len(data) < minimum:
            raise PacketError("short", f"{len(data)} bytes is shorter than any packet")
        magic, version, kind, session, sequence, time_ns = HEADER.unpack_from(data)
        if magic != MAGIC:
            raise PacketError("magic", f"magic {magic!r} is not {MAGIC!r}")
        if version != self.version:
            raise PacketError("version", f"protocol version {version}; this side speaks version {self.version}")
        if kind not in self.payloads or (receives is not None and kind not in receives):
            raise PacketError("kind", f"unknown packet kind {kind}, or one this side does not receive")
        if len(data) != self.sizes[kind]:
            raise PacketError("size", f"a {KIND_NAMES[kind]} packet has {self.sizes[kind]} bytes, not {len(data)}")
        return Header(kind, session, sequence, time_ns)

    def open(self, data: bytes, header: Header, key: bytes | None = None) -> Packet:
        """The packet, once its CRC (version 1) or tag under ``key`` (version 2) is right; else PacketError."""
        end = len(data) - self.trailer
        if self.version == 1:
            (crc,) = CRC.unpack_from(data, end)
            if crc != zlib.crc32(data[:end]):
                raise PacketError("crc", "CRC mismatch: the packet was damaged")
        elif key is None or not auth.tag_ok(key, data[:end], data[end:]):
            raise PacketError("auth", "the tag is wrong: forged, damaged, or of another key or session")
        values = self.payloads[header.kind].unpack_from(data, HEADER.size)
        return Packet(header.kind, header.session, header.sequence, header.time_ns,
                      dict(zip(self.fields[header.kind], values, strict=True)))

    def decode(self, data: bytes, key: bytes | None = None) -> Packet:
        return self.open(data, self.peek(data), key)
