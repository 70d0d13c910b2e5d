"""``ftcap-hil`` command line: one subcommand per job, each in its own module.

The command name is read from the command line first and only that command's module is
imported (:func:`build_parser`), so ``ftcap-hil simulate`` does not import the transport
libraries and ``ftcap-hil allocator`` does not import matplotlib or Dask. ``ftcap-hil --help``
lists every command from the table below without importing any of them.

Errors: an :class:`~ftcap_hil.core.errors.FtcapError` that reaches the top is printed as
``ftcap-hil <command>: <message>`` on stderr and the command exits with its ``exit_code``
(the table in ``ftcap_hil/core/errors.py``); an interrupt (Ctrl-C outside a loop's signal
capture, or a second stop signal, ``ForcedExit``) exits 130.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence
from types import ModuleType

from ftcap_hil.core.errors import ExitCode, FtcapError

# name -> (module with add_arguments(parser) and run(args) -> exit code, help)
COMMANDS: dict[str, tuple[str, str]] = {
    "simulate": ("ftcap_hil.apps.simulate", "Offline closed-loop simulation of a scenario"),
    "campaign": ("ftcap_hil.apps.campaign", "Fault campaign: scenarios x seeds x modes on Dask"),
    "allocator": ("ftcap_hil.apps.allocator", "Run the allocator daemon"),
    "sim": (
        "ftcap_hil.apps.sim",
        "Run the simulated vessel (plant, ESCs on CAN, fault injector)",
    ),
    "gcs": ("ftcap_hil.apps.gcs", "Ground-station script: fly a mission over MAVLink"),
    "demo": ("ftcap_hil.apps.demo", "Start vessel, allocator and ground station on loopback"),
    "can-hub": ("ftcap_hil.apps.can_hub", "Cross-process CAN bus on loopback (no SocketCAN)"),
}


def command_of(argv: Sequence[str]) -> str | None:
    """The command named on ``argv``: its first word that is not an option, if that is a
    command of :data:`COMMANDS` (the top-level options, ``-v``/``-h``, take no value)."""
    for word in argv:
        if not word.startswith("-"):
            return word if word in COMMANDS else None
    return None


def command_module(name: str) -> ModuleType:
    """Import the module of command ``name`` (a key of :data:`COMMANDS`)."""
    return importlib.import_module(COMMANDS[name][0])


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser: every command listed with its help text, and only ``command``'s module
    imported to add its arguments (the others parse no arguments of their own)."""
    parser = argparse.ArgumentParser(prog="ftcap-hil", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more logging")
    sub = parser.add_subparsers(dest="command", required=True)
    for name, (_, text) in COMMANDS.items():
        if name == command:
            mod = command_module(name)
            mod.add_arguments(sub.add_parser(name, help=text, description=mod.__doc__))
        else:
            sub.add_parser(name, help=text)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser(command_of(argv)).parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2) if args.verbose else logging.INFO
    logging.basicConfig(level=level, format="%(asctime)s %(name)s %(levelname)s: %(message)s")
    try:
        return int(command_module(args.command).run(args))
    except FtcapError as e:
        print(f"ftcap-hil {args.command}: {e}", file=sys.stderr)
        return int(e.exit_code)
    except KeyboardInterrupt as e:  # ForcedExit is one
        why = f" ({e})" if str(e) else ""
        print(f"ftcap-hil {args.command}: interrupted{why}", file=sys.stderr)
        return int(ExitCode.INTERRUPTED)


if __name__ == "__main__":
    sys.exit(main())
