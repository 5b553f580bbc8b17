"""`isorig user ...`: the lab's accounts, on the service's machine (backend.accounts).

    isorig user add NAME --role ROLE [--password-file F]   a new account (password from F, else asked, or made)
    isorig user list                                       accounts, roles, state
    isorig user disable NAME | enable NAME                 an account stops (or resumes) acting, at once
    isorig user password NAME [--password-file F]          a new password (its logins end)
    isorig user role NAME ROLE                             a new role
    isorig user token NAME                                 prints a new API token for scripts (shown once)
    isorig user revoke-tokens NAME                         every API token of the account ends

Each takes --database-url (default: the service's, ISORIG_DATABASE_URL or the SQLite file in the data
directory), migrates the schema if it is older, and never prints a secret it was not asked for.
"""

from __future__ import annotations

import getpass
import sys
from pathlib import Path

from isorig.cli import UsageError

PROG = "isorig user"
ROLES = ("viewer", "operator", "approver", "admin")  # backend.accounts.ROLES (imported lazily there)


def register(sub) -> None:
    p = sub.add_parser("user", help="the lab's accounts: add, list, disable, password, role, token",
                       description=__doc__.split("\n\n", 1)[1], formatter_class=_raw())
    verbs = p.add_subparsers(dest="verb", required=True)

    def verb(name: str, help_: str, *, needs_name: bool = True):
        v = verbs.add_parser(name, help=help_)
        if needs_name:
            v.add_argument("name", metavar="NAME")
        v.add_argument("--database-url", default=None, help="SQLAlchemy URL of the records database (default: the "
                       "service's: ISORIG_DATABASE_URL, else the SQLite file in the data directory)")
        v.set_defaults(func=run)
        return v

    add = verb("add", "a new account")
    add.add_argument("--role", required=True, choices=ROLES, help="viewer (reads), operator (runs tests, moves the "
                     "rig), approver (also approves records), admin (also accounts and lab settings)")
    add.add_argument("--password-file", default=None, help="a file whose first line is the password (else it is "
                     "asked on the terminal, or a random one is made and printed when there is no terminal)")
    verb("list", "the accounts, their roles and state", needs_name=False)
    verb("disable", "the account stops acting now: its logins and tokens end (its name stays in every record)")
    verb("enable", "a disabled account may log in again")
    pw = verb("password", "a new password for the account (its logins end)")
    pw.add_argument("--password-file", default=None, help="a file whose first line is the password")
    role = verb("role", "give the account another role")
    role.add_argument("role", choices=ROLES)
    verb("token", "print a new API token for the account (for scripts: Authorization: Bearer <token>); shown once")
    verb("revoke-tokens", "every API token of the account stops working")


def _raw():
    import argparse

    return argparse.RawDescriptionHelpFormatter


def _password(args, *, may_generate: bool) -> tuple[str, bool]:
    """(password, made here): from --password-file, else asked twice on a terminal, else made at random."""
    if args.password_file:
        try:
            lines = Path(args.password_file).read_text().splitlines()
        except OSError as exc:
            raise UsageError(f"{PROG}: cannot read --password-file {args.password_file}: {exc.strerror}") from None
        if not lines or not lines[0]:
            raise UsageError(f"{PROG}: --password-file {args.password_file} is empty; its first line is the password")
        return lines[0], False
    if sys.stdin.isatty():
        first = getpass.getpass(f"password for {args.name}: ")
        if getpass.getpass("again: ") != first:
            raise UsageError(f"{PROG}: the two passwords differ; nothing changed")
        return first, False
    if not may_generate:
        raise UsageError(f"{PROG}: no terminal to ask the password on: give --password-file FILE")
    from backend.accounts import new_password

    return new_password(), True


def run(args) -> int:
    from backend import accounts, db
    from backend.settings import Settings

    url = args.database_url or Settings().resolved_database_url
    try:
        engine = db.make_engine(url)
        db.upgrade(engine)
    except Exception as exc:  # a URL or a server that does not answer: one line, no traceback
        raise UsageError(f"{PROG}: cannot open the database {_safe(url)}: {exc}") from None
    sessions = db.session_factory(engine)
    try:
        with sessions() as session:
            out = _act(args, session, accounts)
            session.commit()
    except accounts.AccountError as exc:
        raise UsageError(f"{PROG} {args.verb}: {exc}") from None
    finally:
        engine.dispose()
    if out:
        print(out)
    return 0


def _act(args, session, accounts) -> str:
    if args.verb == "add":
        password, made = _password(args, may_generate=True)
        user = accounts.add_user(session, args.name, args.role, password)
        said = f"added {user.name} ({user.role})"
        return f"{said}; password: {password}" if made else said
    if args.verb == "list":
        rows = [f"{'name':24s} {'role':9s} state"]
        for u in accounts.users(session):
            state = "disabled" if u.disabled_at else ("token only" if u.password_hash is None else "active")
            rows.append(f"{u.name:24s} {u.role:9s} {state}")
        return "\n".join(rows)
    if args.verb == "disable":
        return f"disabled {accounts.disable_user(session, args.name).name}: its logins and tokens have ended"
    if args.verb == "enable":
        return f"enabled {accounts.enable_user(session, args.name).name}"
    if args.verb == "password":
        password, _ = _password(args, may_generate=False)
        accounts.set_password(session, args.name, password)
        return f"new password set for {args.name}; its logins have ended"
    if args.verb == "role":
        user = accounts.get_user(session, args.name)
        user.role = accounts.check_role(args.role)
        return f"{user.name} is now {args.role}"
    if args.verb == "token":
        return accounts.new_token(session, args.name)
    if args.verb == "revoke-tokens":
        return f"revoked {accounts.revoke_tokens(session, args.name)} token(s) of {args.name}"
    raise UsageError(f"{PROG}: unknown verb {args.verb}")


def _safe(url: str) -> str:
    from sqlalchemy.engine import make_url

    try:
        return make_url(url).render_as_string(hide_password=True)
    except Exception:
        return "(the URL given)"
