"""The report of ``isorig check-rig``: one row per rule (its section, its name, passed or not, the figure
measured and what the row says to the lab), as the table a lab reads and as JSON."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class RuleResult:
    """One rule: the section of docs/rig-protocol.md, what it says, passed (None: not checked), the figure."""

    section: str
    rule: str
    ok: bool | None
    figure: str = ""
    detail: str = ""

    def to_dict(self) -> dict:
        return {"section": self.section, "rule": self.rule, "ok": self.ok, "figure": self.figure,
                "detail": self.detail}


def _section_key(section: str) -> tuple:
    return tuple(int(part) for part in section.lstrip("§").split("."))


@dataclass
class RigCheckReport:
    """Every rule's result, in the order of the document, and the measured figures."""

    url: str
    motion: bool
    results: list[RuleResult] = field(default_factory=list)
    figures: dict = field(default_factory=dict)

    @property
    def failures(self) -> list[RuleResult]:
        return [r for r in self.results if r.ok is False]

    @property
    def ok(self) -> bool:
        return bool(self.results) and not self.failures

    def ordered(self) -> list[RuleResult]:
        return sorted(self.results, key=lambda r: _section_key(r.section))

    def table(self) -> str:
        width = max(len(r.rule) for r in self.results)
        lines = [f"{'':4}  {'section':7}  {'rule':{width}}  measured"]
        for r in self.ordered():
            mark = "PASS" if r.ok else ("FAIL" if r.ok is False else "skip")
            lines.append(f"{mark:4}  {r.section:7}  {r.rule:{width}}  {r.figure}".rstrip())
            if r.detail and r.ok is not True:
                lines.append(f"{'':15}{r.detail}")
        passed = sum(1 for r in self.results if r.ok)
        skipped = sum(1 for r in self.results if r.ok is None)
        failed = self.failures
        verdict = f"{passed} of {len(self.results)} rules passed"
        if skipped:
            verdict += f", {skipped} not checked"
        if failed:
            verdict += f"; FAILED: {', '.join(f'{r.section} {r.rule}' for r in failed)}"
        lines.append(verdict)
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return {"rig": self.url, "ok": self.ok, "motion": self.motion,
                "passed": sum(1 for r in self.results if r.ok), "failed": len(self.failures),
                "rules": [r.to_dict() for r in self.ordered()], "figures": self.figures}
