"""The command log loses at most the row being written when the process is killed."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np

from ftcap_hil.runtime.command_log import CommandLog


def test_every_written_row_is_in_the_file_before_close(tmp_path: Path) -> None:
    log = CommandLog(tmp_path / "commands.csv", 2)
    for i in range(3):
        log.write(i, np.array([0.5, -0.25]))
    lines = (tmp_path / "commands.csv").read_text().splitlines()  # another reader, not closed
    assert lines == ["stamp_ns,u_1,u_2", "0,0.5,-0.25", "1,0.5,-0.25", "2,0.5,-0.25"]
    log.close()


def test_a_sigkilled_writer_leaves_every_row_it_wrote(tmp_path: Path) -> None:
    path = tmp_path / "commands.csv"
    code = (
        "import sys, numpy as np\n"
        "from pathlib import Path\n"
        "from ftcap_hil.runtime.command_log import CommandLog\n"
        f"log = CommandLog(Path({str(path)!r}), 4)\n"
        "for i in range(500):\n"
        "    log.write(i, np.arange(4.0))\n"
        "print('written', flush=True)\n"
        "sys.stdin.read()\n"  # wait to be killed, the log never closed
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "written"
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait(timeout=30)
    rows = path.read_text().splitlines()
    assert len(rows) == 501 and rows[-1] == "499,0,1,2,3", rows[-3:]
