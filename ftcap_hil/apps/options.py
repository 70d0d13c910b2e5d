"""Command-line options shared by several commands."""

from __future__ import annotations

import argparse


def add_set_option(p: argparse.ArgumentParser, what: str, example: str) -> None:
    """``--set SECTION.KEY=VALUE`` (repeatable, collected in ``args.set``): overrides of the
    command's TOML, read by :func:`ftcap_hil.config.toml.apply_overrides`."""
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help=f"override a {what} value (TOML syntax, repeatable), e.g. --set {example}",
    )
