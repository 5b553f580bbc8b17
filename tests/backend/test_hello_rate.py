"""HELLO's rate per source (docs/rig-protocol.md section 9.6, sim/emulator/hello_rate.py): each source has its own
bucket, the table is bounded, and a flood from other sources, however many, leaves the host's bucket whole; and
the host's probe sends its HELLO again within its deadline (backend/drivers/udp.py)."""

from __future__ import annotations

import socket
import threading

import pytest

from backend.drivers.udp import probe
from sim.emulator import auth
from sim.emulator import protocol as proto
from sim.emulator.hello_rate import HELLO_BURST, HELLO_RATE_PER_S, HELLO_SOURCES, HelloBuckets

HOST = ("10.0.0.2", 40001)
FLOOD = ("10.0.0.66", 50000)


def taken(buckets: HelloBuckets, source, n: int, now_s: float) -> int:
    return sum(buckets.take(source, now_s) for _ in range(n))


def test_each_source_has_its_own_bucket_of_10_refilled_at_100_per_s():
    buckets = HelloBuckets()
    assert taken(buckets, FLOOD, 1000, 0.0) == HELLO_BURST  # the flood's own bucket is spent ...
    assert taken(buckets, HOST, 3, 0.0) == 3  # ... the host's is not touched
    assert taken(buckets, FLOOD, 1000, 0.05) == 5  # 50 ms at 100/s
    assert taken(buckets, FLOOD, 1000, 10.0) == HELLO_BURST  # full again, never beyond the burst
    assert HELLO_RATE_PER_S == 100.0
    assert taken(buckets, (HOST[0], HOST[1] + 1), 2, 0.0) == 2  # another port of the host's address: its own


def test_the_table_is_bounded_and_a_flood_of_spoofed_sources_leaves_the_host_its_bucket():
    buckets = HelloBuckets()
    assert buckets.take(HOST, 0.0)
    # 100 000 HELLOs from 10 000 spoofed sources within one second: the table stays at its bound
    for i in range(100_000):
        buckets.take((f"10.1.{i % 10_000 // 250}.{i % 250}", 1024 + i % 7), i * 1e-5)
        assert len(buckets.table) <= HELLO_SOURCES
    assert len(buckets.table) == HELLO_SOURCES and buckets.evicted > 90_000
    # the host, evicted long ago, comes back with a full bucket: all of its HELLOs are checked
    assert taken(buckets, HOST, HELLO_BURST, 1.0) == HELLO_BURST
    # spoofing the host's address from other ports uses up those ports' buckets, never the host's own
    for port in range(2000, 2000 + 10 * HELLO_SOURCES):
        taken(buckets, (HOST[0], port), 20, 1.0)
    assert taken(buckets, HOST, HELLO_BURST, 1.1) == HELLO_BURST


def test_a_source_seen_recently_keeps_its_spent_bucket_while_the_table_has_room():
    buckets = HelloBuckets(max_sources=3)
    taken(buckets, FLOOD, 50, 0.0)
    for i in range(2):  # two more sources: the flood's entry stays, spent
        buckets.take(("10.0.0.1", i), 0.0)
    assert not buckets.take(FLOOD, 0.001)
    assert buckets.status() == {"sources": 3, "max_sources": 3, "evicted": 0, "burst": 10, "rate_per_s": 100.0}


def test_a_bucket_without_room_or_tokens_is_refused():
    for bad in ({"burst": 0}, {"rate_per_s": 0.0}, {"max_sources": 0}):
        with pytest.raises(ValueError, match="HELLO bucket"):
            HelloBuckets(**bad)


def test_the_hosts_probe_sends_its_hello_again_within_its_deadline():
    """A rig that drops the first two HELLOs (a rate, the network) is still found by one probe (0.2 s: 5 HELLOs;
    1 s here, for a loaded machine where this test's rig thread may wait its turn)."""
    security = auth.LinkSecurity(2, bytes(range(32)))
    codec = proto.Codec(2)
    rig = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rig.bind(("127.0.0.1", 0))
    rig.settimeout(1.0)
    got = []

    def answer_the_third():
        while len(got) < 3:
            data, addr = rig.recvfrom(256)
            got.append(codec.decode(data, security.key))
        measurement = (0.001, 2.0, 3.0, 20e5, 0, 0, 2, 0, 0, 1_000_000)
        rig.sendto(codec.encode(proto.ANSWER, 0, 0, 0, *measurement, got[-1].fields["nonce"], b"c" * 16,
                                key=security.key), addr)

    thread = threading.Thread(target=answer_the_third, daemon=True)
    thread.start()
    try:
        answer = probe(f"udp://127.0.0.1:{rig.getsockname()[1]}", timeout_s=1.0, security=security)
    finally:
        thread.join(2.0)
        rig.close()
    assert answer["connected"] and answer["hellos_sent"] >= 3, answer
    assert answer["position_m"] == 0.001 and answer["packets_rejected"] == 2
    assert len({packet.fields["nonce"] for packet in got}) == 3  # a fresh nonce each time
