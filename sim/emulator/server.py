"""The rig emulator: sim.plant's fifth-order rig and isolator in real time behind the rig protocol.

This is what a lab's real-time I/O target runs, played by a process of its own. Every control period
(a tick) it integrates the plant over the period that just ended, reads the sensors (sim.sensors: the same
latency, noise and resolution as the simulated rig) and sends one MEASUREMENT to the host that armed it.
A COMMAND answering that measurement takes effect at the first plant step after it arrives (a command that
misses its period is counted and applied late, the previous one is held meanwhile). The rig holds its own
watchdog: no valid command for ``watchdog_s`` and it closes the valve and disarms itself, whatever the host
does. Before ARM and after DISARM it only answers HELLO; the valve stays closed (0 V).

Faults are injected by ``Faults`` (the ``isorig rig-emulator`` flags), timed from the ARM of the test:
packet loss (each datagram, both ways), added latency and jitter on measurements, a link that drops for
good, outages that come again and again while armed (``Faults.outage``: what a stalled host looks like), the rig's
own overrun in every other test (``Faults.overrun_ms``), a
restart (the rig forgets session and host: nothing moves until a new ARM), a position sensor
stuck, NaN or out of range (silent: the host must see it in the values), and supply pressure loss. A pump
that needs time to reach a new set point (``Faults.supply_rise_s``: after ARM the supply rises, or falls, from
where it was towards what ARM asked, with that time constant) plays the rig of issue 32 whose host judged the
supply on measurement 0.
The link is protocol version 2 (every packet tagged with the lab's key, the session's key derived from the
rig's challenge at ARM: sim.emulator.auth) or, when ``security`` says so, the unauthenticated version 1.
``defects`` break the protocol on purpose (sim.emulator.defects): a rig that does not conform, for testing
``isorig check-rig``. ``tap_port`` plays the lab network as an attacker on it sees it, for the link-attack
tests: a copy of every datagram the rig receives or sends, and a loopback port through which a forged datagram
reaches the rig as if from its host's address, or the host from the rig's (``TAP_*``). The plant is any rig
(``rig``: a lab's rig file), not only isorig's default.

Counters and timings go to ``status()`` and, if asked, to a JSON file a thread rewrites twice a second (file
I/O never runs in the loop: a slow disk once stalled it for 131 ms). Timings are fixed-size histograms
(sim.latency): nothing grows with the length of a test.
"""

from __future__ import annotations

import gc
import heapq
import json
import math
import os
import random
import select
import socket
import threading
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

from ..isolator import Isolator
from ..latency import LatencyHistogram
from ..measurement import STATUS_ARMED, STATUS_COMMAND_MISSED, STATUS_SUPPLY_LOW, STATUS_WATCHDOG
from ..plant import SimulatedPlant
from ..rig import DEFAULT_RIG, RigParameters
from . import auth
from . import protocol as proto
from .defects import check_defects
from .hello_rate import HelloBuckets

SENSOR_FAULTS = ("stuck", "nan", "out-of-range")
# the network tap (``EmulatorConfig.tap_port``): each copy is b">" (to the rig) or b"<" (from the rig), the peer's
# port (u16, little-endian), the datagram; on the forging port b"R" + datagram reaches the rig as if from its host,
# b"H" + datagram goes to the host from the rig's address
TAP_IN, TAP_OUT, FORGE_TO_RIG, FORGE_TO_HOST = b">", b"<", b"R", b"H"
OUT_OF_RANGE_M = 1.0  # what a broken position sensor reads in the out-of-range fault
SUPPLY_LOW_FRACTION = 0.5
SUPPLY_RISE_DONE = 1e-3  # a rising supply this close to its set point (share of it) is set to it: the rise ends
STALE_PERIODS = 10  # a command answering a measurement older than this is stale
SPIN_S = 2e-4  # the loop sleeps until this long before a tick, then polls
#: a tick this late (share of a period) keeps its period from now instead of the old grid: the next tick on the old
#: grid would send its measurement less than half a period after this one's (at once after a tick late by a whole
#: period), before the host could answer this one, so the rig's own stall cost a period the host was blamed for
SLIP_PERIODS = 0.5
#: the status writer holds the GIL for ~3 ms (its JSON) twice a second; with CPython's default switch interval (5 ms)
#: the tick loop, woken by a command, waited for it, and the command was timed that much late (set by the CLI)
GIL_SWITCH_INTERVAL_S = 2e-4
STATUS_EVERY_S = 0.5


@dataclass
class Faults:
    """Fault injection; every time counts from the ARM of the test (None: never)."""

    packet_loss_pct: float = 0.0
    latency_ms: float = 0.0
    jitter_ms: float = 0.0
    drop_link_after_s: float | None = None
    restart_after_s: float | None = None
    sensor_fault: str | None = None
    sensor_fault_after_s: float = 0.0
    supply_loss_after_s: float | None = None
    #: a pump that takes time: after ARM the supply goes from where it was (the previous ARM's setting, or 0 at
    #: the first) towards the asked one with this time constant, instead of at once (None: at once)
    supply_rise_s: float | None = None
    #: while armed, the link goes silent both ways for ``outage_ms`` every ``outage_every_s`` (the first at
    #: outage_every_s): to the rig and to the host alike, this is what a host stalled that long (a shared machine's
    #: hiccup) looks like, repeatably (None: never)
    outage_every_s: float | None = None
    outage_ms: float = 10.0
    #: the rig itself overruns (docs/rig-protocol.md 1.6): its loop sleeps this long once, ``overrun_after_s``
    #: after the ARM, in every other test (the first, third ...): what a shared machine does to the emulator now
    #: and then, repeatably (0: never)
    overrun_ms: float = 0.0
    overrun_after_s: float = 0.030

    def outage(self, t: float | None) -> bool:
        """True within an outage at test time ``t`` (s since the ARM; None: not armed)."""
        if t is None or self.outage_every_s is None or t < self.outage_every_s:
            return False
        return t % self.outage_every_s < self.outage_ms / 1e3

    def check(self) -> None:
        """A clear ValueError for anything out of range."""
        if not (0.0 <= self.packet_loss_pct <= 100.0):
            raise ValueError(f"packet loss = {self.packet_loss_pct!r} % is outside [0, 100] %")
        for name in ("latency_ms", "jitter_ms"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.0 <= value <= 1000.0):
                raise ValueError(f"{name.replace('_ms', '')} = {value!r} ms is outside [0, 1000] ms")
        for name in ("drop_link_after_s", "restart_after_s", "supply_loss_after_s", "sensor_fault_after_s"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} = {value!r} s must be a time >= 0 s")
        if self.supply_rise_s is not None and not (math.isfinite(self.supply_rise_s) and
                                                   0.0 < self.supply_rise_s <= 3600.0):
            raise ValueError(f"supply rise = {self.supply_rise_s!r} s must be a time constant in (0, 3600] s")
        if self.outage_every_s is not None and not (math.isfinite(self.outage_every_s) and self.outage_every_s > 0.0
                                                    and math.isfinite(self.outage_ms)
                                                    and 0.0 < self.outage_ms < 1e3 * self.outage_every_s):
            raise ValueError(f"an outage of {self.outage_ms!r} ms every {self.outage_every_s!r} s: the interval must "
                             "be a time > 0 s and the outage a time > 0 ms shorter than the interval")
        if not (math.isfinite(self.overrun_ms) and 0.0 <= self.overrun_ms <= 1000.0) or \
                not (math.isfinite(self.overrun_after_s) and self.overrun_after_s >= 0.0):
            raise ValueError(f"an overrun of {self.overrun_ms!r} ms at {self.overrun_after_s!r} s: the overrun must be "
                             "within [0, 1000] ms and its time >= 0 s")
        if self.sensor_fault is not None and self.sensor_fault not in SENSOR_FAULTS:
            raise ValueError(f"sensor fault {self.sensor_fault!r} is unknown; allowed: {', '.join(SENSOR_FAULTS)}")


@dataclass
class EmulatorConfig:
    isolator: Isolator
    port: int
    host: str = "127.0.0.1"
    rig: RigParameters = DEFAULT_RIG
    period_s: float = 1e-3
    #: no valid command for this long and the valve closes. 18 ms: the target is "0 V within 20 ms of the last
    #: command", and on this shared VM even a real-time 1 kHz loop wakes 10-13 ms late a few times a minute
    #: (docs/drivers.md), which a 10 ms watchdog took for a lost link
    watchdog_s: float = 0.018
    seed: int = 0
    faults: Faults = field(default_factory=Faults)
    status_file: Path | None = None
    #: where ``rig`` came from, for the start line and ``status()``
    plant_name: str = "isorig default rig (sim.rig)"
    plant_source: str = "sim.rig defaults"
    #: names of ``DEFECTS``: a rig that breaks the protocol on purpose (for testing isorig check-rig)
    defects: tuple[str, ...] = ()
    #: the link's protection (sim.emulator.auth): version 2 with the lab's key, or version 1 without
    security: auth.LinkSecurity = field(default_factory=lambda: auth.LinkSecurity(1, why="no key given"))
    #: for the link-attack tests only: copies of every datagram to 127.0.0.1:tap_port, and a forging port (what an
    #: attacker on the lab network sees and can send, without a relay in the rig's real-time path); None: off
    tap_port: int | None = None
    #: a foreign rig (foreign_rigs.ForeignRigSpec: written from the physics, not from sim's model) played instead
    #: of ``rig`` and ``isolator``; its own specimen is mounted
    foreign_rig: object | None = None

    def make_plant(self, supply_pa: float):
        """The hardware this emulator plays: sim's model with ``rig`` and ``isolator``, or the foreign rig."""
        if self.foreign_rig is not None:
            from ..foreign_plant import ForeignPlant

            return ForeignPlant(self.foreign_rig, supply_pa, self.rig.vertical_load_n, self.period_s)
        return SimulatedPlant(self.rig, self.isolator, supply_pa, self.seed, self.period_s)

    def check(self) -> None:
        if not (1e-4 <= self.period_s <= 0.1):
            raise ValueError(f"period = {self.period_s!r} s is outside [0.0001, 0.1] s")
        if not (self.period_s <= self.watchdog_s <= 1.0):
            raise ValueError(f"watchdog = {self.watchdog_s!r} s must be in [one period, 1] s")
        if not (0 <= self.port <= 65535):
            raise ValueError(f"port {self.port!r} is outside [0, 65535]")
        if self.tap_port is not None and not (1 <= self.tap_port <= 65535):
            raise ValueError(f"tap port {self.tap_port!r} is outside [1, 65535]")
        check_defects(self.defects)
        if self.security.protocol_version == 2 and self.security.key is None:
            raise ValueError("rig protocol 2 needs the lab's key")
        self.rig.check()
        self.faults.check()

    def plant(self) -> dict:
        """The plant's name, where it came from and the parameters that differ from isorig's default rig."""
        if self.foreign_rig is not None:
            return {"name": self.foreign_rig.name, "source": f"foreign_rigs.draw_rig({self.foreign_rig.seed})",
                    "changed": {}}
        changed = {f.name: getattr(self.rig, f.name) for f in fields(RigParameters)
                   if getattr(self.rig, f.name) != getattr(DEFAULT_RIG, f.name)}
        return {"name": self.plant_name, "source": self.plant_source, "changed": changed}


class RigEmulator:
    """One emulated rig on one UDP port (see the module docstring)."""

    def __init__(self, config: EmulatorConfig):
        config.check()
        self.config = config
        self.period_s = config.period_s
        self.faults = config.faults
        self.random = random.Random(config.seed)
        self.plant = config.make_plant(0.0)
        warm = config.make_plant(1e7)
        warm.measure()  # load the compiled plant before serving: a real-time target does not stall at its first ARM
        warm.advance(0.0)
        warm.advance(0.0, 1.0, 0.5)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        self.sock.bind((config.host, config.port))
        self.sock.setblocking(False)
        self.port = self.sock.getsockname()[1]
        self.defects = frozenset(config.defects)
        self.security = config.security
        self.codec = proto.Codec(config.security.protocol_version)
        self.lab_key = config.security.key
        self.challenge = auth.new_nonce()  # version 2: what the next ARM must carry (a new one after each ARM)
        self.hello_buckets = HelloBuckets()  # version 2: HELLO's rate, per source (section 9.6)
        self.send_sock = self.sock
        if "reply-from-other-port" in self.defects:
            self.send_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.send_sock.bind((config.host, 0))
        self.tap = self.forge_sock = None
        self.forge_port = None
        self.last_host_addr = None  # where the last accepted ARM came from (a forged "R" datagram's source)
        if config.tap_port is not None:
            self.tap = ("127.0.0.1", config.tap_port)
            self.forge_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.forge_sock.bind(("127.0.0.1", 0))  # loopback only, whatever the rig's own interface
            self.forge_sock.setblocking(False)
            self.forge_port = self.forge_sock.getsockname()[1]
        self.sockets = [self.sock] + ([self.forge_sock] if self.forge_sock is not None else [])
        self.delayed: list[tuple[float, int, bytes, tuple]] = []
        self.stopped = False
        self.counters = {"ticks": 0, "arms": 0, "disarms": 0, "measurements_sent": 0, "measurements_dropped": 0,
                         "commands_applied": 0, "command_max_abs_v": 0.0, "commands_late": 0, "periods_missed": 0,
                         "incoming_dropped": 0, "outage_dropped": 0, "restarts": 0, "link_dropped": False,
                         "link_dropped_at_sequence": None, "overruns": 0, "ticks_lost": 0, "ticks_slipped": 0}
        self.rejected: dict[str, int] = {}
        self.latency = LatencyHistogram()  # per answered measurement: command arrival - measurement sent
        self.tick_lateness = LatencyHistogram()
        self.watchdog_trips: list[dict] = []
        self._reset_session()

    # --- rig state ------------------------------------------------------------------------------------
    def _reset_session(self) -> None:
        """What a restart forgets: the session, the host, the command, the counters of the test."""
        self.armed = False
        self.plant.hydraulics_off()
        self.session = 0
        self.host_addr = None
        self.sequence = -1
        self.command_v = 0.0
        self.pending: tuple[float, float, int] | None = None  # (command, arrival time, sequence)
        self.last_applied_seq = -1
        self.last_command_time = 0.0
        self.arm_time = None
        self.supply_set_pa = 0.0
        self.vertical_load_n = None
        self.latched_status = 0
        self.overran = False  # Faults.overrun_ms: done in this session
        self.missed = 0
        self.rejected_count = 0
        self.answered_this_period = False
        self.sent_ns: dict[int, int] = {}
        self.stuck_reading = None
        self.last_latency_us = 0
        self.session_key: bytes | None = None  # version 2: the armed session's key
        self.arm_challenge = b""  # ... and the challenge its ARM carried
        self.supply_rise: tuple[float, float, int] | None = None  # (from Pa, to Pa, ARM's tick): the pump rising

    def test_time(self, now: float) -> float | None:
        return None if self.arm_time is None else now - self.arm_time

    def _fault_due(self, after_s: float | None, now: float) -> bool:
        t = self.test_time(now)
        return after_s is not None and t is not None and t >= after_s

    # --- packets in -----------------------------------------------------------------------------------
    def _reject(self, reason: str) -> None:
        self.rejected[reason] = self.rejected.get(reason, 0) + 1
        self.rejected_count += 1

    def receive(self, data: bytes, addr, arrival: float) -> None:
        if self.counters["link_dropped"]:
            return
        if self.armed and self.faults.outage(self.test_time(arrival)):  # a test's link: not the HELLOs before it
            self.counters["outage_dropped"] += 1
            return
        if self.faults.packet_loss_pct and self.random.random() * 100.0 < self.faults.packet_loss_pct:
            self.counters["incoming_dropped"] += 1
            return
        try:
            header = self.codec.peek(data, proto.RIG_RECEIVES)  # a MEASUREMENT or ANSWER sent to a rig: kind
        except proto.PacketError as exc:
            self._reject(exc.reason)
            return
        kind, v2 = header.kind, self.codec.version == 2
        if kind == proto.HELLO and v2 and "no-hello-rate" not in self.defects and \
                not self.hello_buckets.take("everyone" if "shared-hello-rate" in self.defects else addr, arrival):
            self._reject("rate")  # a flood from this source costs the rig no tag to check and no answer
            return
        key = self.lab_key
        if kind in (proto.DISARM, proto.COMMAND) and v2:
            if not self.armed or (header.session != self.session and "echo-other-session" not in self.defects):
                if not (kind == proto.DISARM and header.session == self.session):
                    self._reject("session")
                return  # (a DISARM of the session that last ran, once ended: ignored)
            if addr != self.host_addr and "any-address" not in self.defects:
                self._reject("address")  # not from where the accepted ARM came from
                return
            key = self.session_key
        try:
            packet = self.codec.open(data, header, key)
        except proto.PacketError as exc:
            self._reject(exc.reason)
            return
        if packet.kind == proto.HELLO:  # armed: the test's session and latest sequence; else session 0, sequence 0
            nonce = packet.fields.get("nonce")
            if self.armed:
                self._send_measurement(addr, self.session, max(self.sequence, 0), hello=True, nonce=nonce)
            else:
                self._send_measurement(addr, 0, 0, hello=True, nonce=nonce)
        elif packet.kind == proto.ARM:
            self._arm(packet, addr, arrival)
        elif packet.kind == proto.DISARM:
            if self.armed and packet.session == self.session:
                self._apply(0.0, arrival)
                self.armed = False
                self.plant.hydraulics_off()
                self.counters["disarms"] += 1
            elif packet.session != self.session:
                self._reject("session")
        else:
            self._command(packet, arrival)

    def _arm(self, packet: proto.Packet, addr, arrival: float) -> None:
        supply, load = packet.fields["supply_pressure_pa"], packet.fields["vertical_load_n"]
        rig = self.config.rig
        if packet.session == 0 or not (rig.min_supply_pa <= supply <= rig.max_supply_pa) \
                or not (0.0 <= load <= rig.max_vertical_load_n):
            self._reject("arm")  # no answer: the host learns of it by its timeout, or from a HELLO's count
            return
        challenge = packet.fields.get("challenge", b"")
        if self.armed and packet.session == self.session and challenge == self.arm_challenge:
            if self.codec.version == 2 and addr != self.host_addr:
                self._reject("address")  # the test's ARM again, from elsewhere: a replay
            return  # the host repeats ARM until it hears the rig: already armed
        if self.armed:
            self._reject("busy")  # another host's test runs: it keeps the rig (its disarm or the watchdog frees it)
            return
        if self.codec.version == 2 and not auth.hmac.compare_digest(challenge, self.challenge):
            self._reject("challenge")  # not the rig's current challenge: a replayed ARM, or one before another ARM
            return
        self._reset_session()  # a finished session is not remembered: its ARM again starts it anew, at 0
        self.armed = True
        self.session = packet.session
        self.host_addr = self.last_host_addr = addr
        self.arm_time = arrival
        self.last_command_time = arrival
        self.supply_set_pa = supply
        self.vertical_load_n = load
        if self.faults.supply_rise_s is None:
            self.plant.set_conditions(supply, load)  # the pump's set point and the jack (friction follows the load)
        else:  # the pump starts from where the supply is (the last setting; 0 at the first ARM)
            start = self.plant.supply_pa
            start = start if math.isfinite(start) and start > 0.0 else 0.0
            self.supply_rise = (start, supply, self.counters["ticks"])
            self._pump(start)
        if self.codec.version == 2:
            self.session_key = auth.session_key(self.lab_key, challenge, packet.session)
            self.arm_challenge = challenge
            if "reuse-challenge" not in self.defects:
                self.challenge = auth.new_nonce()  # this ARM can never be accepted again
        self.counters["arms"] += 1

    def _command(self, packet: proto.Packet, arrival: float) -> None:
        """The checks in the order of docs/rig-protocol.md section 5: session, stale, future, stale (age), value."""
        defects = self.defects
        if not self.armed or (packet.session != self.session and "echo-other-session" not in defects):
            self._reject("session")
            return
        seq, u = packet.sequence, packet.fields["command_v"]
        if "accept-stale" not in defects and \
                (seq <= self.last_applied_seq or (self.pending is not None and seq <= self.pending[2])):
            self._reject("stale")  # a duplicate, or older than what this rig already has
            return
        if seq > self.sequence:
            self._reject("future")
            return
        if seq < self.sequence - STALE_PERIODS and "accept-stale" not in defects:
            self._reject("stale")  # more than 10 periods old: the latest measurement is seq + 11 or later
            return
        if not (math.isfinite(u) and abs(u) <= self.config.rig.command_limit_v):
            self._reject("value")
            return
        self.pending = (u, arrival, seq)
        sent = self.sent_ns.pop(seq, None)
        if sent is not None:
            latency_ns = time.perf_counter_ns() - sent
            self.latency.add(latency_ns / 1e6)
            self.last_latency_us = min(int(latency_ns / 1000), proto.U32)
        if seq == self.sequence:
            self.answered_this_period = True
        else:
            self.counters["commands_late"] += 1

    def _apply(self, command_v: float, arrival: float) -> None:
        """A command (or DISARM's 0 V) arriving now: it takes effect within the current period."""
        self.pending = (command_v, arrival, self.pending[2] if self.pending else self.last_applied_seq)

    # --- the tick -------------------------------------------------------------------------------------
    def integrate(self, tick_start: float) -> None:
        """The plant over the period that just ended, the command switching where it arrived."""
        if self.pending is None:
            self.plant.advance(self.command_v)
            return
        u, arrival, seq = self.pending
        self.pending = None
        fraction = max(0.0, (arrival - tick_start) / self.period_s)
        self.plant.advance(self.command_v, u, fraction)
        self.command_v = u
        if seq > self.last_applied_seq:
            self.last_applied_seq = seq
            self.last_command_time = arrival
            self.counters["commands_applied"] += 1
            self.counters["command_max_abs_v"] = max(self.counters["command_max_abs_v"], abs(u))

    def after_tick(self, now: float) -> None:
        faults = self.faults
        if self.armed and not self.answered_this_period and self.sequence >= 0:
            self.missed += 1
            self.counters["periods_missed"] += 1
            status_missed = STATUS_COMMAND_MISSED
        else:
            status_missed = 0
        self.answered_this_period = False
        if self.armed and now - self.last_command_time > self.config.watchdog_s \
                and "no-watchdog" not in self.defects:
            self.watchdog_trips.append({"test_time_s": self.test_time(now),
                                        "after_last_command_ms": (now - self.last_command_time) * 1e3,
                                        "last_command_v": self.command_v})
            self.command_v = 0.0  # the valve closes now: the next period integrates at 0 V
            self.armed = False
            self.plant.hydraulics_off()
            self.latched_status |= STATUS_WATCHDOG  # until the next ARM, in every HELLO answer too
            self.sequence += 1
            # the host hears why, if it still can: the test's session, the next sequence, WATCHDOG and (no command
            # came in this period) COMMAND_MISSED, without ARMED
            self._send_measurement(self.host_addr, self.session, self.sequence, extra_status=status_missed)
            return
        if self._fault_due(faults.restart_after_s, now) and self.counters["restarts"] == 0:
            self.counters["restarts"] += 1
            self.challenge = auth.new_nonce()
            self._reset_session()  # forgets the host: it will hear nothing more from this rig
            self.arm_time = None
            return
        if self._fault_due(faults.drop_link_after_s, now) and not self.counters["link_dropped"]:
            self.counters["link_dropped"] = True
            self.counters["link_dropped_at_sequence"] = self.sequence
        if self._fault_due(faults.supply_loss_after_s, now):
            self.supply_rise = None  # the pump stopped
            t = self.test_time(now) - faults.supply_loss_after_s
            self.plant.lose_supply(t, self.supply_set_pa)
        if self.supply_rise is not None and self.armed:
            self._rise()
        if self.armed:
            self.sequence += 1
            self._send_measurement(self.host_addr, self.session, self.sequence, extra_status=status_missed)

    def _rise(self) -> None:
        """The pump on its way to the set point (``Faults.supply_rise_s``): one exp and one set per tick. Timed
        by the plant's ticks, as the rest of the plant: measurement n is n periods into the rise, and the pump
        pauses with the plant when this process is not scheduled (1.6 of docs/rig-protocol.md)."""
        start, target, k0 = self.supply_rise
        t = (self.counters["ticks"] - k0) * self.period_s
        left = (start - target) * math.exp(-t / self.faults.supply_rise_s)
        if abs(left) <= SUPPLY_RISE_DONE * target:
            left, self.supply_rise = 0.0, None
        self._pump(target + left)

    def _pump(self, supply_pa: float) -> None:
        """The supply the pump delivers now, as a set point the plant follows (``pump_ready=False``: a foreign
        rig's accumulator charges at its pump's own flow; jumping it would also reset its chambers every tick, in
        the middle of a test's first motion; sim's model takes the set point at once either way)."""
        self.plant.set_conditions(supply_pa, self.vertical_load_n, pump_ready=False)

    def _reading(self, m) -> float:
        faults = self.faults
        if faults.sensor_fault is None or not self._fault_due(faults.sensor_fault_after_s, time.perf_counter()):
            return m.position_m
        if faults.sensor_fault == "nan":
            return math.nan
        if faults.sensor_fault == "out-of-range":
            return OUT_OF_RANGE_M
        if self.stuck_reading is None:
            self.stuck_reading = m.position_m
        return self.stuck_reading

    def _send_measurement(self, addr, session: int, seq: int, extra_status: int = 0, hello: bool = False,
                          nonce: bytes | None = None) -> None:
        if addr is None or self.counters["link_dropped"]:
            return
        m = self.plant.measure()
        supply = m.supply_pressure_pa
        status = self.latched_status | extra_status
        if self.armed:
            status |= STATUS_ARMED
            if supply < SUPPLY_LOW_FRACTION * self.supply_set_pa:
                status |= STATUS_SUPPLY_LOW
        now_ns = time.perf_counter_ns()
        values = (self._reading(m), m.force_n, m.load_pressure_pa, supply, status, min(self.missed, proto.U32),
                  min(self.rejected_count, proto.U32), max(self.last_applied_seq, 0), self.last_latency_us,
                  int(round(self.period_s * 1e9)))
        if self.codec.version == 1:
            packet = self.codec.encode(proto.MEASUREMENT, session, seq, now_ns, *values)
        elif hello:
            packet = self.codec.encode(proto.ANSWER, session, seq, now_ns, *values, nonce, self.challenge,
                                       key=self.lab_key)
        else:
            packet = self.codec.encode(proto.MEASUREMENT, session, seq, now_ns, *values, key=self.session_key)
        if not hello:
            self.sent_ns[seq] = now_ns
            self.sent_ns.pop(seq - STALE_PERIODS - 1, None)
        if self.faults.packet_loss_pct and self.random.random() * 100.0 < self.faults.packet_loss_pct:
            self.counters["measurements_dropped"] += 1
            return
        if self.armed and self.faults.outage(self.test_time(time.perf_counter())):
            self.counters["outage_dropped"] += 1
            return
        delay = self.faults.latency_ms
        if self.faults.jitter_ms:
            delay += self.random.uniform(-self.faults.jitter_ms, self.faults.jitter_ms)
        if delay > 0:
            heapq.heappush(self.delayed, (time.perf_counter() + delay / 1e3, seq, packet, addr))
        else:
            self._sendto(packet, addr)

    def _sendto(self, packet: bytes, addr) -> None:
        try:
            self.send_sock.sendto(packet, addr)
            self.counters["measurements_sent"] += 1
        except OSError:
            self.counters["measurements_dropped"] += 1
            return
        self._copy(TAP_OUT, addr, packet)

    # --- the network tap (attack tests) ---------------------------------------------------------------
    def _copy(self, direction: bytes, addr, data: bytes) -> None:
        if self.tap is not None:
            try:
                self.forge_sock.sendto(direction + addr[1].to_bytes(2, "little") + data, self.tap)
            except OSError:
                pass  # nobody listens: a tap never holds the rig

    def _forged(self, now: float) -> None:
        """Datagrams of the forging port: to the rig as if from its host, or to the host from the rig."""
        while True:
            try:
                data = self.forge_sock.recv(self.codec.max_packet + 64)
            except (BlockingIOError, InterruptedError, OSError):
                return
            kind, packet = data[:1], data[1:]
            if kind == FORGE_TO_RIG and self.last_host_addr is not None:
                self.receive(packet, self.last_host_addr, now)
            elif kind == FORGE_TO_HOST and self.last_host_addr is not None:
                try:
                    self.send_sock.sendto(packet, self.last_host_addr)
                except OSError:
                    pass

    # --- the real-time loop ---------------------------------------------------------------------------
    def _pump_until(self, due: float) -> None:
        """Receive and send delayed packets until the wall clock reaches ``due``."""
        while True:
            now = time.perf_counter()
            while self.delayed and self.delayed[0][0] <= now:
                _, _, packet, addr = heapq.heappop(self.delayed)
                if not self.counters["link_dropped"]:
                    self._sendto(packet, addr)
            if now >= due:
                return
            wait = due - now - (SPIN_S if self.armed else 0.0)  # an idle rig need not be on time to the us
            if self.delayed:
                wait = min(wait, self.delayed[0][0] - now)
            readable, _, _ = select.select(self.sockets, [], [], max(0.0, wait))
            if self.sock in readable:
                while True:
                    try:
                        data, addr = self.sock.recvfrom(self.codec.max_packet + 64)
                    except (BlockingIOError, InterruptedError):
                        break
                    except OSError:
                        break
                    self._copy(TAP_IN, addr, data)
                    self.receive(data, addr, time.perf_counter())
            if self.forge_sock is not None and self.forge_sock in readable:
                self._forged(time.perf_counter())

    def serve(self, duration_s: float | None = None) -> None:
        """Run ticks until ``stop()`` (or for ``duration_s``)."""
        writer = None
        if self.config.status_file is not None:
            writer = threading.Thread(target=self._status_writer, daemon=True, name="isorig-emulator-status")
            writer.start()
        t0 = start = time.perf_counter()
        k = 0
        while not self.stopped:
            tick_start = t0 + k * self.period_s
            due = tick_start + self.period_s
            if self.faults.overrun_ms and self.armed and not self.overran and self.counters["arms"] % 2 == 1 \
                    and self._fault_due(self.faults.overrun_after_s, time.perf_counter()):
                self.overran = True
                time.sleep(self.faults.overrun_ms / 1e3)  # the rig's own stall: nothing read, nothing sent
            self._pump_until(due)
            now = time.perf_counter()
            late = now - due
            self.tick_lateness.add(late * 1e3)
            stall = 0.0
            if late > SLIP_PERIODS * self.period_s:
                # this process was not scheduled for a while (its own stall, not the link's): like a real target
                # after an overrun (docs/rig-protocol.md 1.6) it does not catch up, neither on the ticks it lost
                # nor by sending the next measurement right after this one, and keeps its period from now on;
                # the watchdog does not count the periods lost
                lost = int(late / self.period_s)
                self.counters["ticks_slipped"] += 1
                if lost:
                    self.counters["overruns"] += 1
                    self.counters["ticks_lost"] += lost
                stall = lost * self.period_s
                t0, k = now - self.period_s, 0
                tick_start = t0
            self.integrate(tick_start)
            if not self.armed:  # the sensors read every period, sent or not: their delay line holds no stale reading
                self.plant.measure()
            if stall and self.last_command_time < due:
                # after integrate: a command that arrived before the stall and is applied now dates from before it
                self.last_command_time += stall
            self.after_tick(now)
            self.counters["ticks"] += 1
            k += 1
            if duration_s is not None and now - start >= duration_s:
                break
        self.stopped = True
        if writer is not None:
            writer.join()
        self.write_status()

    def _status_writer(self) -> None:
        while not self.stopped:
            self.write_status()
            time.sleep(STATUS_EVERY_S)

    def stop(self) -> None:
        self.stopped = True

    def close(self) -> None:
        self.sock.close()
        if self.send_sock is not self.sock:
            self.send_sock.close()
        if self.forge_sock is not None:
            self.forge_sock.close()

    def status(self) -> dict:
        return {"pid": os.getpid(), "port": self.port, "written_monotonic_s": time.monotonic(),  # the clock of the
                # whole machine (CLOCK_MONOTONIC): a reader knows whether the file was written after it asked
                **self.security.describe(),
                "isolator": self.config.isolator.name,
                "plant": self.config.plant(), "defects": sorted(self.defects), "period_s": self.period_s,
                "watchdog_s": self.config.watchdog_s, "faults": asdict(self.faults),
                "armed": self.armed, "session": self.session, "sequence": self.sequence,
                "supply_pa": self.supply_set_pa, "supply_measured_pa": self.plant.supply_pa,
                "vertical_load_n": self.vertical_load_n,
                "command_v": self.command_v, "position_m": self.plant.position_m,
                "counters": dict(self.counters), "rejected": dict(self.rejected),
                "hello_sources": self.hello_buckets.status(),
                "command_latency": self.latency.summary(above_ms=self.period_s * 1e3),
                "tick_lateness": self.tick_lateness.summary(above_ms=1.0),
                "watchdog_trips": list(self.watchdog_trips),
                # the garbage collector of this process: the objects frozen at start (never scanned: `isorig
                # rig-emulator`), the collections of each generation so far (a full one over everything took 9-12 ms)
                "collector": {"frozen_objects": gc.get_freeze_count(),
                              "collections": [g["collections"] for g in gc.get_stats()]}}

    def write_status(self) -> None:
        path = self.config.status_file
        if path is None:
            return
        tmp = Path(str(path) + ".tmp")
        tmp.write_text(json.dumps(self.status(), indent=1))
        os.replace(tmp, path)
