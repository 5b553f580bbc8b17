"""``check_driver(driver)``: the conformance check a rig driver's author runs, in the spirit of gymnasium's
``check_env``.

It arms the rig at a low supply pressure and holds the valve at 0 V (the table does not move), so it can
run on a real rig with the specimen mounted. It checks what isorig relies on:

- ``describe()``: a name, a positive control period, a positive command limit, the standard channels
  with their SI units;
- ``disarm()`` is idempotent, before ``arm``, after it, with ``success`` True or False;
- one ``Measurement`` per period: the sequence (``period``) rises by one per period (lost periods aside,
  never backwards), ``time_s`` is ``period`` times the control period, readings are finite at rest, the
  rig says it is armed;
- a real-time rig keeps its period on the wall clock (within 20 % over the run);
- NaN, infinite and out-of-range commands are refused with ``CommandRefused`` and the rig runs on;
  the limit itself is accepted;
- a fault surfaces as an error, never as a hang: ``inject_fault(driver)`` (optional, e.g. stopping an
  emulator) must make ``wait_next_period`` or ``read`` raise ``RigFault``, or ``fault()`` report it, within
  ``fault_timeout_s``; after ``disarm``, ``wait_next_period`` must return or raise within that time too.

Returns a ``DriverReport``; raises ``DriverCheckError`` listing every failure when ``raise_on_failure``.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from sim.measurement import STATUS_ARMED, Measurement

from .base import ArmConditions, CommandRefused, RigDescription, RigDriver, RigFault

REQUIRED_UNITS = {"position_m": "m", "force_n": "N", "load_pressure_pa": "Pa", "supply_pressure_pa": "Pa"}
CHECK_SUPPLY_PA = 20e5  # 20 bar: the table is held at 0 V anyway
PERIOD_TOLERANCE = 0.2


class DriverCheckError(AssertionError):
    """A driver does not conform; the message lists every failed check."""


@dataclass
class DriverReport:
    """Each check's name, whether it passed, and what was seen."""

    results: list[tuple[str, bool, str]] = field(default_factory=list)

    def add(self, name: str, ok: bool, detail: str = "") -> bool:
        self.results.append((name, bool(ok), detail))
        return ok

    @property
    def failures(self) -> list[tuple[str, bool, str]]:
        return [r for r in self.results if not r[1]]

    @property
    def ok(self) -> bool:
        return not self.failures

    def __str__(self) -> str:
        return "\n".join(f"{'ok  ' if ok else 'FAIL'} {name}" + (f": {detail}" if detail else "")
                         for name, ok, detail in self.results)


def _within(seconds: float, call: Callable[[], object]) -> tuple[str, object]:
    """Run ``call`` in a thread: ('returned', value), ('raised', exception) or ('hung', None)."""
    box: dict = {}

    def target():
        try:
            box["value"] = call()
        except BaseException as exc:  # noqa: BLE001 - reported, not swallowed
            box["error"] = exc

    thread = threading.Thread(target=target, daemon=True, name="isorig-check-driver")
    thread.start()
    thread.join(seconds)
    if thread.is_alive():
        return "hung", None
    if "error" in box:
        return "raised", box["error"]
    return "returned", box.get("value")


def _check_description(desc: RigDescription, report: DriverReport) -> None:
    report.add("describe() gives a RigDescription", isinstance(desc, RigDescription), type(desc).__name__)
    report.add("a name and a kind", bool(desc.name) and bool(desc.kind), f"{desc.name!r}, {desc.kind!r}")
    report.add("a positive, finite control period", math.isfinite(desc.control_period_s)
               and desc.control_period_s > 0, f"{desc.control_period_s!r} s")
    report.add("a positive, finite command limit", math.isfinite(desc.command_limit_v) and desc.command_limit_v > 0,
               f"{desc.command_limit_v!r} V")
    units = {c.name: c.unit for c in desc.channels}
    wrong = {name: units.get(name) for name, unit in REQUIRED_UNITS.items() if units.get(name) != unit}
    report.add("the standard channels in SI units", not wrong,
               "missing or wrong: " + ", ".join(f"{n} ({u})" for n, u in wrong.items()) if wrong else "")


def _check_measurement(m, period_s: float, report: DriverReport, label: str) -> bool:
    if not report.add(f"{label}: read() gives a Measurement", isinstance(m, Measurement), type(m).__name__):
        return False
    ok = report.add(f"{label}: time_s is period x control period",
                    isinstance(m.period, int) and m.period >= 0 and abs(m.time_s - m.period * period_s) < 1e-9,
                    f"period {m.period!r}, time {m.time_s!r} s")
    ok &= report.add(f"{label}: finite readings at rest", m.is_finite(),
                     f"position {m.position_m!r} m, force {m.force_n!r} N, P_L {m.load_pressure_pa!r} Pa, "
                     f"P_s {m.supply_pressure_pa!r} Pa")
    ok &= report.add(f"{label}: the rig reports itself armed", bool(m.status & STATUS_ARMED), f"status {m.status:#x}")
    return ok


def check_driver(driver: RigDriver, periods: int = 200, inject_fault: Callable[[RigDriver], None] | None = None,
                 fault_timeout_s: float = 2.0, raise_on_failure: bool = True) -> DriverReport:
    """Check ``driver`` against the driver protocol (see the module docstring)."""
    report = DriverReport()
    desc = driver.describe()
    _check_description(desc, report)
    period_s, limit = desc.control_period_s, desc.command_limit_v
    outcome, value = _within(fault_timeout_s, lambda: driver.disarm(success=True))
    report.add("disarm() before arm() is harmless", outcome == "returned", f"{outcome} {value!r}"[:200])

    driver.arm(ArmConditions(CHECK_SUPPLY_PA))
    try:
        first = driver.read()
        _check_measurement(first, period_s, report, "after arm")
        seen, backwards, gaps = [first.period], 0, 0
        t0 = time.perf_counter()
        for _ in range(periods):
            driver.write(0.0)
            driver.wait_next_period()
            m = driver.read()
            if m.period <= seen[-1]:
                backwards += 1
            gaps += max(0, m.period - seen[-1] - 1)
            seen.append(m.period)
        elapsed = time.perf_counter() - t0
        report.add("the sequence rises every period, never backwards", backwards == 0,
                   f"{backwards} backward or repeated of {periods}; {gaps} period(s) lost")
        _check_measurement(m, period_s, report, f"after {periods} periods")
        if desc.realtime:
            expected = (seen[-1] - seen[0]) * period_s
            report.add("a real-time rig keeps its period on the wall clock",
                       abs(elapsed - expected) <= PERIOD_TOLERANCE * expected + 2 * period_s,
                       f"{seen[-1] - seen[0]} periods in {elapsed:.3f} s, expected {expected:.3f} s")
        for bad in (math.nan, math.inf, -math.inf, 1.5 * limit, -1.5 * limit):
            try:
                driver.write(bad)
                refused = False
            except CommandRefused:
                refused = True
            report.add(f"write({bad!r} V) is refused", refused, "" if refused else "accepted")
        for edge in (limit, -limit, 0.0):
            try:
                driver.write(edge)
                accepted = True
            except CommandRefused as exc:
                accepted = False
                detail = str(exc)
            report.add(f"write({edge:g} V) within the limit is accepted", accepted, "" if accepted else detail)
            driver.wait_next_period()
        _check_measurement(driver.read(), period_s, report, "after the refused commands")
    finally:
        driver.disarm(success=True)
    for success in (True, False):
        outcome, value = _within(fault_timeout_s, lambda s=success: driver.disarm(success=s))
        report.add(f"disarm(success={success}) again is harmless", outcome == "returned", f"{outcome} {value!r}"[:200])
    outcome, value = _within(fault_timeout_s, driver.wait_next_period)
    report.add("wait_next_period() after disarm returns or raises, never hangs", outcome != "hung",
               f"{outcome} {type(value).__name__}")

    if inject_fault is None:
        report.add("a fault surfaces as an error (not checked: no inject_fault given)", True)
    else:
        driver.arm(ArmConditions(CHECK_SUPPLY_PA))
        try:
            inject_fault(driver)

            def until_fault():
                end = time.perf_counter() + fault_timeout_s
                while time.perf_counter() < end:
                    driver.write(0.0)
                    driver.wait_next_period()
                    driver.read()
                    if driver.fault() is not None:
                        return driver.fault()
                return None

            outcome, value = _within(fault_timeout_s + 1.0, until_fault)
            surfaced = (outcome == "raised" and isinstance(value, RigFault)) or (outcome == "returned" and value)
            report.add("an injected fault surfaces as RigFault or fault(), not a hang", surfaced,
                       f"{outcome}: {value}"[:300])
        finally:
            driver.disarm(success=False)

    if raise_on_failure and not report.ok:
        raise DriverCheckError(f"the driver {desc.name!r} does not conform:\n{report}")
    return report
