"""The authenticated rig link (rig protocol 2, docs/rig-protocol.md section 9): the key file, the tags, the
policy for a link without a key, and the attacks of issue 21 part 4 run against a real test.

The attack test runs ``isorig rig-emulator`` (with the lab's key) and ``isorig simulate --rig ...
--rig-key-file ...`` as processes of their own, talking to each other directly. The emulator's network tap
(``--tap-port``) lets this process do what an attacker on the lab network can: see every datagram and send
from any address, the rig's and the host's included. It has no key. (A relay process between host and rig did
this before, with two extra hops per period; measured then, the rig missed 57 to 607 commands of 4000 through
it, 9 to 17 direct. With a busy loop and another session's real-time emulator on the machine, direct runs
missed 62 to 485 too and two runs nobody attacked differed by up to 10.9 um: the 0.1 % of the amplitude, 10 um,
is then tight; without the busy loop, 53 to 100 and within 0.6 um, tapped or not.)
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from emulator import ISORIG, Emulator, read_record, simulate_on

from backend.drivers.udp import UdpRig, probe
from sim.emulator import auth
from sim.emulator import protocol as proto
from sim.emulator.hello_rate import HELLO_BURST, HELLO_RATE_PER_S
from sim.measurement import STATUS_ARMED, STATUS_INTERLOCK

# real time against the rig emulator in its own process: scripts/test.sh runs these alone, after the others
pytestmark = pytest.mark.realtime

V2 = proto.Codec(2)
AMPLITUDE_M = 0.01  # simulate_on's
NATURAL_DROPS = 3  # drops nobody forged that a loaded 2-CPU machine may add in a test (a command counted stale)


def new_key_file(tmp_path: Path, name: str = "lab.key") -> Path:
    return auth.write_key_file(tmp_path / name)


# --- the key file, the tags, the policy --------------------------------------------------------------------------

def test_a_key_file_is_refused_unless_private_and_long_enough(tmp_path):
    path = new_key_file(tmp_path)
    assert oct(path.stat().st_mode & 0o777) == "0o600" and len(auth.load_key_file(path)) == 32
    path.chmod(0o640)
    with pytest.raises(auth.KeyFileError, match=r"group or others \(mode 0640\).*chmod 600"):
        auth.load_key_file(path)
    short = tmp_path / "short.key"
    short.write_text("ab" * 31 + "\n")
    short.chmod(0o600)
    with pytest.raises(auth.KeyFileError, match="31 bytes of key is too short.*at least 32 bytes"):
        auth.load_key_file(short)
    short.write_text("ab" * 32 + "c\n")
    with pytest.raises(auth.KeyFileError, match="65 hex digits is an odd number"):
        auth.load_key_file(short)
    raw = tmp_path / "raw.key"
    raw.write_bytes(bytes(range(200, 248)))
    raw.chmod(0o600)
    assert auth.load_key_file(raw) == bytes(range(200, 248))
    with pytest.raises(auth.KeyFileError, match="No such file"):
        auth.load_key_file(tmp_path / "missing.key")


def test_rig_key_new_writes_a_private_key_and_never_overwrites(tmp_path):
    path = tmp_path / "lab.key"
    made = subprocess.run([*ISORIG, "rig-key", "new", str(path)], capture_output=True, text=True)
    assert made.returncode == 0, made.stderr
    assert path.stat().st_mode & 0o777 == 0o600 and len(bytes.fromhex(path.read_text())) == 32
    again = subprocess.run([*ISORIG, "rig-key", "new", str(path)], capture_output=True, text=True)
    assert again.returncode == 2 and "never overwritten" in again.stderr and "Traceback" not in again.stderr
    path.chmod(0o644)
    refused = subprocess.run([*ISORIG, "simulate", "--rig", "udp://127.0.0.1:9", "--rig-key-file", str(path),
                              "--out", str(tmp_path / "out")], capture_output=True, text=True)
    assert refused.returncode == 2 and "chmod 600" in refused.stderr and "Traceback" not in refused.stderr


def test_v2_packets_carry_a_tag_that_a_wrong_key_or_a_flipped_bit_breaks():
    key = os.urandom(32)
    data = V2.encode(proto.COMMAND, 7, 12, 5, -3.5, key=key)
    assert len(data) == proto.V2_SIZES[proto.COMMAND] == 48
    assert V2.decode(data, key).fields == {"command_v": -3.5}
    for bad in (V2.encode(proto.COMMAND, 7, 12, 5, -3.5, key=os.urandom(32)),
                data[:30] + bytes([data[30] ^ 1]) + data[31:], data[:-1] + bytes([data[-1] ^ 0x80])):
        with pytest.raises(proto.PacketError) as exc:
            V2.decode(bad, key)
        assert exc.value.reason == "auth"
    with pytest.raises(proto.PacketError) as exc:
        V2.decode(proto.encode(proto.HELLO, 0, 0, 0), key)  # a version 1 packet
    assert exc.value.reason == "version"
    answer = V2.encode(proto.ANSWER, 0, 0, 1, *([0.0] * 4), 0, 0, 0, 0, 0, 10**6, b"n" * 16, b"c" * 16, key=key)
    assert len(answer) == 128 and V2.decode(answer, key).fields["challenge"] == b"c" * 16
    assert auth.session_key(key, b"c" * 16, 1) != auth.session_key(key, b"c" * 16, 2)


def test_the_test_vectors_of_the_protocol_page_hold():
    """docs/rig-protocol.md section 9.8: what a C target compares its HMAC and layout with."""
    doc = (Path(__file__).parents[2] / "docs" / "rig-protocol.md").read_text()
    vectors = doc[doc.index("**Test vectors**"):doc.index("### 9.9")]
    hexes = [chunk.replace(" ", "") for chunk in vectors.split("`")[1::2]
             if len(chunk) >= 32 and set(chunk) <= set("0123456789abcdef ")]
    key = bytes(range(32))
    hello = V2.encode(proto.HELLO, 0, 0, 1000, b"\x11" * 16, key=key)
    s_key = auth.session_key(key, b"\x22" * 16, 0x01020304)
    arm = V2.encode(proto.ARM, 0x01020304, 0, 2000, 100e5, 0.0, b"\x22" * 16, key=key)
    command = V2.encode(proto.COMMAND, 0x01020304, 5, 3000, 1.5, key=s_key)
    assert hexes == [x.hex() for x in (hello[:40], hello[40:], s_key, arm[:40], arm[40:], command[:32],
                                       command[32:])], hexes


def test_a_link_without_a_key_is_named_or_on_loopback(tmp_path):
    assert auth.resolve_security("127.0.0.1", env={}).describe() == {
        "protocol_version": 1, "authenticated": False,
        "unauthenticated_because": "loopback without a key file (any process on this machine can reach it)"}
    with pytest.raises(ValueError, match="needs the lab's key.*--rig-protocol 1"):
        auth.resolve_security("192.0.2.7", env={})
    assert not auth.resolve_security("192.0.2.7", protocol_version="1", env={}).authenticated
    assert not auth.resolve_security("192.0.2.7", env={"ISORIG_RIG_PROTOCOL": "1"}).authenticated
    key = new_key_file(tmp_path)
    with pytest.raises(ValueError, match="not both"):
        auth.resolve_security("192.0.2.7", key, 1, env={})
    with pytest.raises(ValueError, match="protocol 2 needs the lab's key"):
        auth.resolve_security("127.0.0.1", protocol_version=2, env={})
    secured = auth.resolve_security("192.0.2.7", env={"ISORIG_RIG_KEY_FILE": str(key)})
    assert secured.authenticated and secured.protocol_version == 2
    refused = subprocess.run([*ISORIG, "rig-emulator", "--port", "0", "--host", "0.0.0.0"], capture_output=True,
                             text=True, timeout=60, env={**os.environ, "ISORIG_RIG_KEY_FILE": "",
                                                         "ISORIG_RIG_PROTOCOL": ""})
    assert refused.returncode == 2 and "--rig-protocol 1" in refused.stderr


def test_the_report_says_when_the_link_was_not_authenticated():
    from backend.reports.data import link_text

    assert link_text({"protocol_version": 1, "authenticated": False, "received": 10}).startswith(
        "link not authenticated (rig protocol 1), 10 packets received")
    assert link_text({"protocol_version": 2, "authenticated": True, "host_stall_max_ms": 1.5}) == \
        "authenticated (rig protocol 2), longest host stall 1.5 ms"


# --- against the emulator process ------------------------------------------------------------------------------

class Sniffer(threading.Thread):
    """The emulator's tap: every datagram the rig received or sent (but the attacker's own), with the latest
    session and sequence seen."""

    def __init__(self):
        super().__init__(daemon=True)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.1)
        self.port = self.sock.getsockname()[1]
        self.packets: list[tuple[str, int, int, int, bytes]] = []  # (direction, kind, session, sequence, data)
        self.host_port = None
        self.session, self.sequence = 0, -1
        self.new_measurement = threading.Event()
        self.stopped = False
        self.ignored_ports: set[int] = set()  # the attacker's: what it sent itself is no traffic of the link

    def run(self):
        while not self.stopped:
            try:
                data = self.sock.recv(4096)
            except TimeoutError:
                continue
            direction, port, packet = chr(data[0]), int.from_bytes(data[1:3], "little"), data[3:]
            if port in self.ignored_ports:
                continue
            self.host_port = port
            _, _, kind, session, sequence, _ = proto.HEADER.unpack_from(packet)
            self.packets.append((direction, kind, session, sequence, packet))
            if direction == "<" and kind == proto.MEASUREMENT:
                self.session, self.sequence = session, sequence
                self.new_measurement.set()

    def captured(self, direction: str, kind: int, session: int | None = None) -> list[bytes]:
        return [p[4] for p in list(self.packets) if p[0] == direction and p[1] == kind
                and (session is None or p[2] == session)]


class Attacker:
    """A socket on the lab network without the key; through the tap's forging port it also sends from the rig's
    address (to the host) and from the host's address (to the rig)."""

    def __init__(self, rig_port: int, control_port: int, sniffer: Sniffer):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        sniffer.ignored_ports.add(self.sock.getsockname()[1])
        self.rig, self.control, self.sniffer = ("127.0.0.1", rig_port), ("127.0.0.1", control_port), sniffer
        self.key = os.urandom(32)  # not the lab's
        self.sent_to_rig: dict[str, int] = {}  # by the reason the rig must drop it for
        self.sent_to_host: dict[str, int] = {}

    def _count(self, table: dict, reason: str, n: int = 1) -> None:
        table[reason] = table.get(reason, 0) + n

    def to_rig(self, data: bytes, reason: str | None, spoofed: bool = False) -> None:
        """To the rig from this socket, or ``spoofed`` from the host's address."""
        if spoofed:
            self.sock.sendto(b"R" + data, self.control)
        else:
            self.sock.sendto(data, self.rig)
        if reason:
            self._count(self.sent_to_rig, reason)

    def to_host(self, data: bytes, reason: str, spoofed: bool = False) -> None:
        """To the host's port from this socket, or ``spoofed`` from the rig's address."""
        if spoofed:
            self.sock.sendto(b"H" + data, self.control)
        else:
            self.sock.sendto(data, ("127.0.0.1", self.sniffer.host_port))
        self._count(self.sent_to_host, reason)

    def answers(self, wait_s: float = 0.1) -> int:
        """Datagrams the rig sent back to this socket."""
        n, end = 0, time.monotonic() + wait_s
        self.sock.settimeout(0.01)
        while time.monotonic() < end:
            try:
                self.sock.recv(4096)
                n += 1
            except TimeoutError:
                pass
        return n

    def next_measurement(self) -> tuple[int, int]:
        self.sniffer.new_measurement.clear()
        self.sniffer.new_measurement.wait(1.0)
        return self.sniffer.session, self.sniffer.sequence


def _attack(a: Attacker, baseline_session: int) -> dict:
    """Every attack of the issue on the running test; returns what the attacker saw."""
    sniffer = a.sniffer
    session, seq = a.next_measurement()
    seen = {}
    # a HELLO without the key (and a version 1 one): no answer, so no session revealed
    a.to_rig(V2.encode(proto.HELLO, 0, 0, 0, auth.new_nonce(), key=a.key), "auth")
    a.to_rig(proto.encode(proto.HELLO, 0, 0, 0), "version")
    seen["answers_to_hello_without_key"] = a.answers(0.1)
    # DISARM of the running session, forged: from the host's address and from elsewhere
    for _ in range(3):
        a.to_rig(V2.encode(proto.DISARM, session, 0, 0, key=a.key), "auth", spoofed=True)
        a.to_rig(V2.encode(proto.DISARM, session, 0, 0, key=a.key), "address")
    # ... then an ARM of its own (with the challenge it sniffed), and the test's own ARM replayed from elsewhere
    sniffed_challenge = sniffer.captured("<", proto.ANSWER)[-1][-32:-16]  # the ANSWER's challenge (spent)
    for _ in range(3):
        a.to_rig(V2.encode(proto.ARM, 0x1234567, 0, 0, 20e5, 0.0, sniffed_challenge, key=a.key), "auth")
    a.to_rig(sniffer.captured(">", proto.ARM, session)[0], "address")
    a.to_rig(sniffer.captured(">", proto.ARM, baseline_session)[0], "busy")  # an old test's ARM
    # +10 V commands answering each measurement as soon as it is sniffed (before the host's answer), and forged
    # measurements (INTERLOCK, 50 mm) to the host, from the rig's and the host's address and from elsewhere
    for _ in range(150):
        session, seq = a.next_measurement()
        a.to_rig(V2.encode(proto.COMMAND, session, seq, 0, 10.0, key=a.key), "auth", spoofed=True)
        a.to_rig(V2.encode(proto.COMMAND, session, seq, 0, 10.0, key=a.key), "address")
        forged = V2.encode(proto.MEASUREMENT, session, seq + 1, 0, 0.05, 0.0, 0.0, 100e5,
                           STATUS_ARMED | STATUS_INTERLOCK, 0, 0, seq, 0, 10**6, key=a.key)
        a.to_host(forged, "auth", spoofed=True)
        a.to_host(forged, "address")
    # replays of what was sniffed: this test's commands and measurements, an old test's commands and DISARM
    for data in sniffer.captured(">", proto.COMMAND, session)[-60:-10]:
        a.to_rig(data, "stale", spoofed=True)
    for data in sniffer.captured("<", proto.MEASUREMENT, session)[-60:-10]:
        a.to_host(data, "stale", spoofed=True)
    for data in sniffer.captured(">", proto.COMMAND, baseline_session)[-20:]:
        a.to_rig(data, "session", spoofed=True)
    a.to_rig(sniffer.captured(">", proto.DISARM, baseline_session)[0], "session", spoofed=True)
    for data in sniffer.captured("<", proto.MEASUREMENT, baseline_session)[-20:]:
        a.to_host(data, "session", spoofed=True)
    # a HELLO flood: 5000 without the key and 200 replays of the host's own HELLO, at 10 per ms
    hello = sniffer.captured(">", proto.HELLO)[-1]
    garbage = V2.encode(proto.HELLO, 0, 0, 0, auth.new_nonce(), key=a.key)
    t0 = time.monotonic()
    for i in range(5200):
        a.to_rig(hello if i % 26 == 0 else garbage, None)
        if i % 10 == 9:
            time.sleep(max(0.0, t0 + (i + 1) / 10_000 - time.monotonic()))
    flood_s = time.monotonic() - t0
    seen["flood_answers"] = a.answers(0.2)
    seen["flood_s"] = flood_s
    a._count(a.sent_to_rig, "flood", 5200)
    return seen


def rcvbuf_errors() -> int:
    """UDP datagrams the kernel dropped for a full receive buffer, machine-wide (/proc/net/snmp): never seen by
    any process, so never counted (nor applied)."""
    try:
        lines = [line.split() for line in Path("/proc/net/snmp").read_text().splitlines() if line.startswith("Udp:")]
        return int(lines[1][lines[0].index("RcvbufErrors")])
    except (OSError, ValueError, IndexError):
        return 0


def _attacked_run(tmp_path: Path, url: str, key: Path, emulator: Emulator, sniffer: Sniffer, control: int,
                  baseline_session: int, name: str) -> dict:
    """One test under every attack; what the attacker sent and saw, and the rig's and the host's counts."""
    before = emulator.fresh_status()["rejected"]
    dropped_before = rcvbuf_errors()
    attacker = Attacker(emulator.port, control, sniffer)
    previous = sniffer.session  # the last run's (the baseline's, or an earlier attacked run's)
    run = simulate_on(url, tmp_path / name, "--rig-key-file", str(key), cycles=8, wait=False)
    while sniffer.sequence < 300 or sniffer.session in (previous, baseline_session):
        time.sleep(0.01)
        assert run.poll() is None, run.stdout.read()
    seen = _attack(attacker, baseline_session)
    output = run.communicate(timeout=60)[0]
    summary = json.loads((tmp_path / name / "summary.json").read_text())
    # after the test: its ARM replayed, from the host's address and from elsewhere: the challenge is spent
    arm = sniffer.captured(">", proto.ARM, sniffer.session)[0]
    attacker.to_rig(arm, "challenge", spoofed=True)
    attacker.to_rig(arm, "challenge")
    seen["after_answers"] = attacker.answers(0.1)
    status = emulator.fresh_status()
    # a datagram the kernel dropped (a receive buffer full while a loaded machine did not schedule its reader)
    # reaches nobody: the counts may miss at most those (machine-wide, other sessions' included)
    unseen = rcvbuf_errors() - dropped_before
    seen["kernel_dropped_machine_wide"] = unseen
    assert run.returncode == 0 and summary["status"] == "completed", output
    assert summary["reason"] in (None, ""), summary["reason"]
    assert seen["answers_to_hello_without_key"] == 0 and seen["after_answers"] == 0
    assert not status["armed"]
    # the rig: every forged packet dropped and counted by its reason
    rejected = {k: v - before.get(k, 0) for k, v in status["rejected"].items() if v - before.get(k, 0)}
    sent = dict(attacker.sent_to_rig)
    flood = sent.pop("flood")
    answered = seen["flood_answers"]
    assert answered <= HELLO_BURST + HELLO_RATE_PER_S * (seen["flood_s"] + 0.3), seen
    # (a loaded machine may add a natural drop or two, a late command counted stale: NATURAL_DROPS at most)
    flood_dropped = rejected.pop("rate", 0) + rejected["auth"] - sent.pop("auth")
    assert flood - unseen <= flood_dropped + answered <= flood + NATURAL_DROPS, (rejected, sent, seen)
    rejected.pop("auth")
    assert all(rejected.get(reason, 0) >= n - unseen for reason, n in sent.items()), (rejected, sent, seen)
    assert sum(rejected.values()) <= sum(sent.values()) + NATURAL_DROPS, (rejected, sent)
    # the host: every forged or replayed measurement dropped and counted
    link = summary["link"]
    host = link["rejected_by_reason"]
    assert all(host.get(reason, 0) >= n - unseen for reason, n in attacker.sent_to_host.items()), (link, seen)
    assert sum(host.values()) <= sum(attacker.sent_to_host.values()) + NATURAL_DROPS, link
    assert link["protocol_version"] == 2 and link["authenticated"] is True
    assert link["rig_packets_rejected"] >= sum(attacker.sent_to_rig.values()) - flood - 2
    return {"summary": summary, "seen": seen, "rig_rejected": rejected, "host_rejected": host}


def attack_figures(tmp_path: Path) -> dict:
    """A run nobody attacks, then one under every attack, on one emulator; the figures of both (and the checks of
    ``_attacked_run``). Also run by scripts/link_attack.py, which measures the tracking target over several runs."""
    key = new_key_file(tmp_path)
    sniffer = Sniffer()
    sniffer.start()
    emulator = Emulator(tmp_path, "--rig-key-file", str(key), "--tap-port", str(sniffer.port))
    try:
        code, base, output = simulate_on(emulator.url, tmp_path / "base", "--rig-key-file", str(key), cycles=8)
        assert code == 0, output  # the run nobody attacks
        baseline_session = int.from_bytes(sniffer.captured(">", proto.ARM)[-1][8:12], "little")
        result = _attacked_run(tmp_path, emulator.url, key, emulator, sniffer, emulator.forge_port,
                               baseline_session, "attacked")
        counters = emulator.fresh_status()["counters"]
    finally:
        sniffer.stopped = True
        emulator.stop()
    host_max_v = max(float(np.max(np.abs(read_record(tmp_path / run)["voltage_v"]))) for run in ("base", "attacked"))
    difference_m = abs(result["summary"]["rms_y_minus_r_m"] - base["rms_y_minus_r_m"])
    return {"rms_unattacked_m": base["rms_y_minus_r_m"], "rms_attacked_m": result["summary"]["rms_y_minus_r_m"],
            "difference_pct_of_amplitude": 100 * difference_m / AMPLITUDE_M,
            "rig_applied_max_abs_v": counters["command_max_abs_v"], "host_sent_max_abs_v": host_max_v,
            "rig_rejected": result["rig_rejected"], "host_rejected": result["host_rejected"],
            "flood": result["seen"], "host_stall_max_ms": result["summary"]["link"]["host_stall_max_ms"],
            "rig_commands_missed": [base["link"]["rig_commands_missed"],
                                    result["summary"]["link"]["rig_commands_missed"]]}


def test_an_attacker_without_the_key_changes_nothing_in_a_running_test(tmp_path):
    figures = attack_figures(tmp_path)
    print(json.dumps(figures))
    # nothing the attacker sent was applied: its +10 V commands would be the largest the rig ever applied. At most
    # the host's largest, not equal to it: a command the rig missed (late) was never applied (2.96882 V applied
    # against 2.96893 V sent in a CI run where the rig missed 105 commands)
    assert 0.5 * figures["host_sent_max_abs_v"] < figures["rig_applied_max_abs_v"] <= \
        figures["host_sent_max_abs_v"] + 1e-4, figures
    assert figures["host_sent_max_abs_v"] < 9.0, figures
    # the tracking of the run nobody attacked. The target, within 0.1 % of the amplitude, is measured over several
    # runs by scripts/link_attack.py: on a loaded 2-CPU machine two runs nobody attacks differ by up to 0.11 % (the
    # module's docstring), timing and not the attack. An attack that got through (issue 21: +10 V commands applied,
    # tracking from 0.04 to 0.80 mm) is far beyond this bound.
    assert figures["difference_pct_of_amplitude"] <= 0.5, figures


def test_version_1_is_spoken_when_named_and_says_it_is_not_authenticated(tmp_path):
    key = new_key_file(tmp_path)
    emulator = Emulator(tmp_path, "--rig-protocol", "1")
    try:
        code, summary, output = simulate_on(emulator.url, tmp_path / "v1", "--rig-protocol", "1", cycles=2)
        assert code == 0, output
        assert summary["link"]["protocol_version"] == 1 and summary["link"]["authenticated"] is False
        assert "host_stall_max_ms" in summary["link"]
        details = UdpRig.from_url(emulator.url, protocol_version=1).describe().details
        assert details["authenticated"] is False and "named" in details["unauthenticated_because"]
        wrong = probe(emulator.url, key_file=str(key))  # a v2 host: the v1 rig drops its HELLO (version)
        assert not wrong["connected"] and "protocol v2" in wrong["detail"]
        # each HELLO of the probe (sent again within its 0.2 s) dropped and counted
        assert emulator.fresh_status()["rejected"].get("version") == wrong["hellos_sent"] >= 2
    finally:
        emulator.stop()


def test_a_rig_with_another_key_is_named_as_such(tmp_path):
    emulator = Emulator(tmp_path, "--rig-key-file", str(new_key_file(tmp_path, "rig.key")))
    try:
        answer = probe(emulator.url, key_file=str(new_key_file(tmp_path, "other.key")))
        assert not answer["connected"] and "protocol v2" in answer["detail"]
        assert emulator.fresh_status()["rejected"].get("auth") == answer["hellos_sent"] >= 2
        code, _, output = simulate_on(emulator.url, tmp_path / "out", "--rig-key-file",
                                      str(tmp_path / "other.key"), cycles=2)
        assert code == 2 and "nothing moved" in output and "Traceback" not in output
    finally:
        emulator.stop()


def test_the_service_runs_a_test_over_the_authenticated_link_and_shows_it(tmp_path):
    from conftest import AUTH, make_settings, sine_test, wait_for
    from fastapi.testclient import TestClient

    from backend.app import create_app

    key = new_key_file(tmp_path)
    emulator = Emulator(tmp_path, "--rig-key-file", str(key))
    try:
        settings = make_settings(tmp_path, rig=emulator.url, rig_key_file=key)
        with TestClient(create_app(settings)) as client:
            rig = client.get("/api/rig").json()
            assert rig["rig"]["authenticated"] is True and rig["rig"]["protocol_version"] == 2, rig["rig"]
            assert "authenticated" in rig["rig"]["protocol"] and rig["link"]["connected"], rig
            r = client.post("/api/tests?start=true", json=sine_test(speed=1.0), headers=AUTH)
            assert r.status_code == 201, r.text
            record = wait_for(client, r.json()["id"])
            assert record["status"] == "completed", (record["reason"], record["summary"].get("link"))
            link = record["summary"]["link"]
            assert link["authenticated"] is True and link["protocol_version"] == 2 and link["rejected"] == 0, link
            assert 0.0 <= link["host_stall_max_ms"] < 50.0
    finally:
        status = emulator.stop()
    assert status["counters"]["arms"] == 1 and "auth" not in status["rejected"]  # (a loaded machine: a stale)
