"""The isorig rig protocol, version 1: one UDP datagram per control period each way (docs/rig-protocol.md).

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

MAGIC = b"ISRG"
VERSION = 1
MEASUREMENT, COMMAND, ARM, DISARM, HELLO = 1, 2, 3, 4, 5
KIND_NAMES = {MEASUREMENT: "measurement", COMMAND: "command", ARM: "arm", DISARM: "disarm", HELLO: "hello"}

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
