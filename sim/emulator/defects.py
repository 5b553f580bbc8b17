"""Ways for the rig emulator to break the rig protocol on purpose: a rig that does not conform, so that
``isorig check-rig`` is seen to fail on it (``isorig rig-emulator --defect NAME``). Never for a real test."""

from __future__ import annotations

DEFECTS = {
    "no-watchdog": "the watchdog never trips",
    "echo-other-session": "applies the commands of any session (does not compare the session of a COMMAND)",
    "accept-stale": "applies stale commands (duplicates, older than the one held, more than 10 periods old)",
    "reply-from-other-port": "sends from another port than the one the host sent to",
    "no-hello-rate": "(protocol 2) answers every HELLO, however many",
    "shared-hello-rate": "(protocol 2) one HELLO bucket for every sender: a flood from anyone starves the host's HELLO",
    "any-address": "(protocol 2) applies commands from any address, not only the ARM's",
    "reuse-challenge": "(protocol 2) keeps its challenge after an ARM, so a finished session's ARM arms it again",
}


def check_defects(names) -> None:
    """A clear ValueError for a name that is not one of ``DEFECTS``."""
    unknown = [name for name in names if name not in DEFECTS]
    if unknown:
        raise ValueError(f"defect {unknown[0]!r} is unknown; allowed: {', '.join(DEFECTS)}")
