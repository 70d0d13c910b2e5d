"""``ftcap-hil`` command line: one subcommand per job, each in its own module.

Subcommands are registered lazily (name -> module:function) so ``ftcap-hil simulate`` does
not import the networking stacks and the daemon does not import matplotlib.

Errors: an :class:`~ftcap_hil.core.errors.FtcapError` that reaches the top is printed as
``ftcap-hil <command>: <message>`` on stderr and the command exits with its ``exit_code``
(the table in ``ftcap_hil/core/errors.py``); an interrupt (Ctrl-C outside a loop's signal
capture, or a second stop signal, ``ForcedExit``) exits 130.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import logging
import sys
from collections.abc import Callable, Sequence

from ftcap_hil.core.errors import ExitCode, FtcapError

# name -> (module with add_arguments(parser) and run(args) -> exit code, help)
_COMMANDS: dict[str, tuple[str, str]] = {
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


def _available() -> dict[str, tuple[str, str]]:
    return {
        name: (mod, text)
        for name, (mod, text) in _COMMANDS.items()
        if importlib.util.find_spec(mod) is not None
    }


def build_parser() -> tuple[
    argparse.ArgumentParser, dict[str, Callable[[argparse.Namespace], int]]
]:
    parser = argparse.ArgumentParser(prog="ftcap-hil", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more logging")
    sub = parser.add_subparsers(dest="command", required=True)
    runners: dict[str, Callable[[argparse.Namespace], int]] = {}
    for name, (mod_name, text) in _available().items():
        mod = importlib.import_module(mod_name)
        p = sub.add_parser(name, help=text, description=mod.__doc__)
        mod.add_arguments(p)
        runners[name] = mod.run
    return parser, runners


def main(argv: Sequence[str] | None = None) -> int:
    parser, runners = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2) if args.verbose else logging.INFO
    logging.basicConfig(level=level, format="%(asctime)s %(name)s %(levelname)s: %(message)s")
    try:
        return int(runners[args.command](args))
    except FtcapError as e:
        print(f"ftcap-hil {args.command}: {e}", file=sys.stderr)
        return int(e.exit_code)
    except KeyboardInterrupt as e:  # ForcedExit is one
        why = f" ({e})" if str(e) else ""
        print(f"ftcap-hil {args.command}: interrupted{why}", file=sys.stderr)
        return int(ExitCode.INTERRUPTED)


if __name__ == "__main__":
    sys.exit(main())
