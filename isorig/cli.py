"""The `isorig` command line. Each subcommand lives in isorig/commands/<name>.py with
``register(subparsers)``; heavy imports happen inside the command, so `isorig --help` is instant.
Bad arguments exit with code 2 and one clear line, never a traceback.
"""

from __future__ import annotations

import argparse
import gc
import importlib
import sys
import time

COMMAND_MODULES = ("simulate", "bench", "analyze", "report", "serve", "bench_stream", "identify", "compare",
                   "rig_emulator", "check_rig", "bench_rig", "hybrid", "move", "rig_key", "user")


class UsageError(Exception):
    """Bad command-line input: printed as one line, exit code 2."""


class Parser(argparse.ArgumentParser):
    def error(self, message):  # one clear line instead of usage + message
        raise UsageError(f"{self.prog}: {message} (see '{self.prog} --help')")


class Progress:
    """A one-line progress display on a terminal (stderr); silent when not a terminal."""

    def __init__(self, label: str, stream=None):
        self.stream = stream or sys.stderr
        self.label = label
        self.active = self.stream.isatty()
        self.t0 = time.perf_counter()

    def __call__(self, fraction: float):
        if self.active:
            self.stream.write(f"\r{self.label}: {100 * fraction:5.1f} %  ({time.perf_counter() - self.t0:.1f} s)")
            self.stream.flush()

    def close(self):
        if self.active:
            self.stream.write("\n")


def output_folder(path: str, prog: str):
    """The --out folder, created with its parents; a folder that cannot be made is a usage error."""
    from pathlib import Path

    out = Path(path)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"{prog}: cannot create --out {out}: {exc.strerror}") from None
    return out


def whole_number(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None


def build_parser() -> Parser:
    parser = Parser(prog="isorig", description="Control and test dashboard for seismic-isolator test rigs.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=Parser)
    for name in COMMAND_MODULES:
        importlib.import_module(f"isorig.commands.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    try:
        return _run(argv)
    except KeyboardInterrupt:  # also while the first imports run
        print("isorig: interrupted", file=sys.stderr)
        return 130


def _run(argv: list[str] | None) -> int:
    from sim.isolator import IsolatorError
    from sim.profiles import ProfileError

    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        code = args.func(args)
        if argv is None:  # the program itself (not a test calling main): skip the collector's pass at exit
            gc.freeze()
        return code
    except UsageError as exc:
        print(str(exc), file=sys.stderr)
        return 2
    except (IsolatorError, ProfileError, ValueError) as exc:
        print(f"isorig: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
