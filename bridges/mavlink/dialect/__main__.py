"""``python -m bridges.mavlink.dialect [--out DIR | --install [--dir DIR]]``.

Without options it fills the private cache used at run time and prints the cached file's
path; ``--shared`` then makes that cache readable (never writable) by other users, for an
image built at install time by root and run by another user. ``--out DIR`` writes
``DIR/ftcap.py``. ``--install`` writes ``ftcap.py`` (and the XML)
into the installed pymavlink's ``dialects/v20`` so that pymavlink's tools decode the
project's messages: ``mavproxy.py --dialect=ftcap``, ``mavlogdump.py --dialect ftcap``, or
``MAVLINK_DIALECT=ftcap`` for any other ``mavutil`` program (with or without ``MAVLINK20``;
mavlogdump ignores the variable: its ``--dialect`` defaults to ardupilotmega).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bridges.mavlink.dialect import install, load, render, share


def main(argv: list[str] | None = None) -> int:
    """Write, install or cache the module; print the path(s); return 0 (1 on an OSError)."""
    parser = argparse.ArgumentParser(prog="python -m bridges.mavlink.dialect")
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--out", type=Path, help="write ftcap.py into this directory")
    group.add_argument(
        "--install", action="store_true", help="install for pymavlink tools (--dialect ftcap)"
    )
    parser.add_argument("--dir", type=Path, help="with --install: this dialects directory")
    parser.add_argument(
        "--shared", action="store_true", help="make the filled cache readable by all users"
    )
    args = parser.parse_args(argv)
    try:
        if args.install:
            for path in install(args.dir):
                sys.stdout.write(f"{path}\n")
            sys.stdout.write(
                "use: mavproxy.py --dialect=ftcap, mavlogdump.py --dialect ftcap, "
                "MAVLINK_DIALECT=ftcap for other mavutil programs\n"
            )
            return 0
        if args.out is None:
            path = Path(str(load().__file__))
            if args.shared:
                share(path)
            sys.stdout.write(f"{path}\n")
            return 0
        args.out.mkdir(parents=True, exist_ok=True)
        target = args.out / "ftcap.py"
        target.write_text(render(), encoding="utf-8")
    except OSError as e:
        sys.stderr.write(f"cannot write the MAVLink dialect: {e}\n")
        return 1
    sys.stdout.write(f"{target}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
