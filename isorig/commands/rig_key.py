"""`isorig rig-key new FILE`: a new key file for the authenticated rig link (docs/rig-protocol.md, protocol
version 2), and the `--rig-key-file` / `--rig-protocol` flags every rig command shares."""

from __future__ import annotations

import sys

from isorig.cli import UsageError


def register(sub) -> None:
    p = sub.add_parser("rig-key", help="make the key file the host and the rig's I/O target share (rig protocol 2)")
    verbs = p.add_subparsers(dest="verb", required=True)
    new = verbs.add_parser("new", help="write a new random 256-bit key (64 hex digits) to a new file of mode 0600",
                           description="Writes a new random key (32 bytes as 64 hex digits) to FILE, readable by its "
                           "owner only. Give the same file to the host (--rig-key-file, ISORIG_RIG_KEY_FILE) and to "
                           "the rig's I/O target. An existing file is never overwritten.")
    new.add_argument("file", metavar="FILE")
    new.set_defaults(func=run)


def run(args) -> int:
    from sim.emulator.auth import KeyFileError, write_key_file

    try:
        path = write_key_file(args.file)
    except KeyFileError as exc:
        raise UsageError(f"isorig rig-key new: {exc}") from None
    print(f"isorig rig-key: wrote a new 256-bit key to {path} (mode 0600); give the same file to the rig's I/O "
          "target and to the host (--rig-key-file or ISORIG_RIG_KEY_FILE)", file=sys.stderr)
    return 0


def add_link_flags(p) -> None:
    """--rig-key-file and --rig-protocol on a command that talks to a UDP rig."""
    p.add_argument("--rig-key-file", metavar="FILE", default=None,
                   help="UDP rig: the lab's key file (rig protocol 2, every packet authenticated; `isorig rig-key "
                        "new FILE` makes one; default ISORIG_RIG_KEY_FILE)")
    p.add_argument("--rig-protocol", choices=("1", "2"), default=None,
                   help="UDP rig: 2 (default: authenticated, needs --rig-key-file) or 1 (unauthenticated, for a "
                        "lab's bring-up or an existing v1 target; default ISORIG_RIG_PROTOCOL). Without a key, only "
                        "a rig on loopback runs, unauthenticated, unless 1 is named")


def link_security(command: str, rig: str, args):
    """The link's protection from the flags (sim.emulator.auth.resolve_security), or a usage error."""
    from backend.drivers.udp import parse_udp_url
    from sim.emulator.auth import resolve_security

    try:
        host, _ = parse_udp_url(rig)
        return resolve_security(host, args.rig_key_file, args.rig_protocol)
    except ValueError as exc:
        raise UsageError(f"isorig {command}: {exc}") from None


def link_options(security, args) -> dict:
    """What the UDP driver and ``probe`` are given (backend.drivers.udp): the key file (its path, never the key)
    and the version only if named, so that they resolve the link as ``security`` did, with the same reason."""
    return {"key_file": security.key_file, "protocol_version": args.rig_protocol}
