"""``python -m bridges.mavlink.dialect [--out DIR]``: generate the ftcap dialect module.

Without ``--out`` it fills the cache used at run time and prints the cached file's path.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bridges.mavlink.dialect import load, render


def main(argv: list[str] | None = None) -> int:
    """Write the module (``--out DIR``) or fill the cache; print the path; return 0."""
    parser = argparse.ArgumentParser(prog="python -m bridges.mavlink.dialect")
    parser.add_argument("--out", type=Path, help="write ftcap.py into this directory")
    args = parser.parse_args(argv)
    if args.out is None:
        sys.stdout.write(f"{load().__file__}\n")
        return 0
    args.out.mkdir(parents=True, exist_ok=True)
    target = args.out / "ftcap.py"
    target.write_text(render(), encoding="utf-8")
    sys.stdout.write(f"{target}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
