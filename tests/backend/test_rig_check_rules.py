"""check-rig's rules as data (backend/drivers/rig_check/rules.py): every rule of the table has a check, a probe, a
section that docs/rig-protocol.md has, and a message for the lab, and a failing rule's message reaches the report.
No rig: the checks judge measurements made here."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from backend.drivers.rig_check import CHECKS, PROBES, RULES, RigCheck
from backend.drivers.rig_check.probes import DROPS, Refusal, RefusedArms
from backend.drivers.rig_check.rules import RULE
from sim.emulator import auth

PROTOCOL = Path(__file__).resolve().parents[2] / "docs" / "rig-protocol.md"


def protocol_sections() -> set[str]:
    """The sections of docs/rig-protocol.md: "## 3.", "**3.1 ...**" and "### 9.6" headings."""
    text = PROTOCOL.read_text()
    found = set(re.findall(r"^## (\d+)\. ", text, re.M))
    found |= set(re.findall(r"^\*\*(\d+\.\d+) ", text, re.M))
    found |= set(re.findall(r"^### (\d+\.\d+) ", text, re.M))
    return {f"§{number}" for number in found}


@pytest.fixture(params=[1, 2], ids=["v1", "v2"])
def rig_check(request) -> RigCheck:
    """A check of a rig that is never reached (nothing is sent here), speaking protocol 1 or 2."""
    security = auth.LinkSecurity(1, why="a test") if request.param == 1 else auth.LinkSecurity(
        2, key=auth.new_nonce() * 2, key_file="test.key")
    check = RigCheck("udp://127.0.0.1:9", security=security, motion=True)
    assert check.security.protocol_version == request.param
    return check


def test_every_rule_has_a_check_a_probe_a_protocol_section_and_a_message(rig_check):
    sections = protocol_sections()
    assert {"§1.5", "§3.2", "§5", "§9.6"} <= sections  # the parsing finds the document's sections
    context = rig_check.context()
    assert len({rule.id for rule in RULES}) == len(RULES)
    for rule in RULES:
        assert rule.check_name in CHECKS, rule.id
        assert rule.section in sections, (rule.id, rule.section)
        assert rule.fails.format(**context).strip() and rule.text.format(**context).strip(), rule.id
        assert "{" not in rule.fails.format(**context) + rule.text.format(**context), rule.id
        assert rule.when in ("", "v1", "v2", "motion"), rule.id
        if rule.probe:
            assert rule.probe in PROBES, rule.id
        else:
            assert rule.id == "ran-to-end"  # fed by the exception that ended the check, not by a probe
        if rule.probe == "dropped":
            assert rule.arg in DROPS, rule.id
    assert set(CHECKS) == {rule.check_name for rule in RULES}  # no check without a rule
    # the rules of one probe are next to each other: RigCheck runs a probe once for the rules it feeds
    fed = [(rule.probe, rule.arg) for rule in RULES if rule.probe]
    runs = [key for i, key in enumerate(fed) if i == 0 or fed[i - 1] != key]
    assert len(runs) == len(set(runs)), [key for key in runs if runs.count(key) > 1]
    # one row name per rule of a run: the report's rows are told apart by name
    names = [(r.section, r.text.format(**context)) for r in RULES if rig_check.applies(r)]
    assert len(set(names)) == len(names)


def test_a_failing_rules_message_reaches_the_report(rig_check):
    rule = RULE["arm-session-0"]
    message = rule.fails.format(**rig_check.context())
    answered = RefusedArms([], Refusal(answered=2, armed=True, rejected=0))  # the rig armed for session 0
    assert rig_check.judge(rule, answered) is False
    row = rig_check.report.results[-1]
    assert (row.section, row.rule, row.ok) == (rule.section, rule.text, False)
    assert row.detail.startswith("the rig answered with 2 measurement(s)") and row.detail.endswith(message)
    assert message in rig_check.report.table() and "FAILED: §3.2 an ARM with session 0" in rig_check.report.table()
    assert rig_check.report.to_dict()["rules"][-1]["detail"] == row.detail
    refused = RefusedArms([], Refusal(answered=0, armed=False, rejected=1))  # refused in silence, counted once
    assert rig_check.judge(rule, refused) is True
    assert message not in rig_check.report.results[-1].detail
