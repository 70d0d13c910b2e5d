"""What a run wrote, read back for the tests' judgement."""

from __future__ import annotations

import csv
from pathlib import Path


def float_rows(path: Path) -> list[dict[str, float]]:
    """The rows of a numeric CSV with a header (a ground station's ``timeseries.csv``, the
    vessel's ``--record``), every value as a float."""
    with open(path, newline="") as fh:
        return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(fh)]
