"""``check_rig(url)``: the conformance check of a rig's real-time I/O target against docs/rig-protocol.md.

What ``check_driver`` (backend/drivers/check.py) does for a Python driver, for a target written in any
language: it talks raw UDP with the reference codec (sim/emulator/protocol.py) and checks every rule of the
protocol document, one row per rule naming its section (``isorig check-rig``, docs/drivers.md):

- HELLO: the answer, session 0 and sequence 0 when unarmed, the table's position, the counters; armed, the
  test's session and latest sequence; replies from the address and port it was sent to;
- ARM: refused in silence and counted outside the rig's ranges (``rig``: the lab's rig file) or with session 0;
  accepted with measurement 0 and the counters from zero; repeated, busy, and again after the test ended;
- the sequence (+1 per period), the period, ``command_sequence``, ``COMMAND_MISSED``, a late command applied;
- each drop reason (short, size, magic, version, kind, crc, session, stale, future, value, busy, arm), seen in
  the rig's ``packets_rejected`` and in the command not being applied (``command_sequence`` not reaching it);
- DISARM (the stream stops), the rig unarmed (silent, commands dropped), the watchdog (its time from the last
  command and from ARM, its last measurement, stale commands not feeding it);
- version 2 (section 9): a HELLO without the key unanswered, HELLO's rate, a HELLO answered while a keyless flood
  from another socket runs (the rate is per source), tags, the ARM's address and challenge;
- with ``motion``: the direction of the table, the signs of ``load_pressure_pa`` (its change from the rest
  before each push, ``pressure_change``: whatever specimen is mounted) and ``force_n``, the position a HELLO
  reports after the table moved.

Every command it sends is 0.0 V, except the ones a conforming rig must refuse (NaN, infinite, 1.2 x the command
limit: never applied), and, with ``motion``, +-``motion_v`` until the table has moved 0.3 mm (stopped at once
beyond 1 mm). ARMs outside the rig's ranges are sent too: a conforming rig refuses them.

The rig's watchdog (10-20 ms) closes the valve whenever this process is late: a probe it interrupts is run
again with a new session, up to ``TRIES`` times, and the row says so.

The package: ``rules.py``, the rules as data (``RULES``: id, section, name, what a failure tells the lab, the
probe that feeds it) and their small checks (``CHECKS``); ``probes.py``, what is sent and timed (each probe
returns a measurement, judging nothing); ``link.py``, the sockets and an armed session's stream; ``check.py``,
``RigCheck``, which runs the probes in the table's order and judges each rule; ``report.py``, the report.
"""

from .check import CHECK_RR_PRIORITY, MOTION_MAX_V, RigCheck, check_rig
from .link import Disturbed, Link, Received, RigUnreachable, Silent, Stream, Tripped
from .probes import (
    HELLO_BURST,
    HELLO_BURST_SENT,
    HELLO_FLOOD_SENT,
    HELLO_RATE_PER_S,
    MOTION_PRESSURE_MIN_PA,
    MOTION_PRESSURE_SIGMAS,
    MOTION_REST_PERIODS,
    MOTION_STEP_M,
    MOTION_STOP_M,
    PROBES,
    SILENCE_S,
    STALE_PERIODS,
    STEADY_PERIODS,
    TRIES,
    VALUE_FACTOR,
    WATCHDOG_GIVE_UP_S,
    WATCHDOG_TRIPS,
    pressure_change,
)
from .report import RigCheckReport, RuleResult
from .rules import (
    CHECKS,
    HELLO_FOLLOW_M,
    POSITION_AGREE_M,
    RULES,
    WATCHDOG_MAX_S,
    WATCHDOG_MIN_S,
    WATCHDOG_TOLERANCE_S,
    Rule,
    Verdict,
)

__all__ = [
    "CHECKS", "CHECK_RR_PRIORITY", "HELLO_BURST", "HELLO_BURST_SENT", "HELLO_FLOOD_SENT", "HELLO_FOLLOW_M",
    "HELLO_RATE_PER_S", "MOTION_MAX_V", "MOTION_PRESSURE_MIN_PA", "MOTION_PRESSURE_SIGMAS", "MOTION_REST_PERIODS",
    "MOTION_STEP_M", "MOTION_STOP_M", "POSITION_AGREE_M", "PROBES", "RULES", "SILENCE_S", "STALE_PERIODS",
    "STEADY_PERIODS", "TRIES", "VALUE_FACTOR", "WATCHDOG_GIVE_UP_S", "WATCHDOG_MAX_S", "WATCHDOG_MIN_S",
    "WATCHDOG_TOLERANCE_S", "WATCHDOG_TRIPS", "Disturbed", "Link", "Received", "RigCheck", "RigCheckReport",
    "RigUnreachable", "Rule", "RuleResult", "Silent", "Stream", "Tripped", "Verdict", "check_rig", "pressure_change",
]
