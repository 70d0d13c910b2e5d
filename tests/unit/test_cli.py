"""The command line is lazy: only the named command's module is imported, so the offline
commands run where the transport libraries cannot be imported at all."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from ftcap_hil.apps import cli
from tests.support.no_transports import TRANSPORTS, env_without_transports


@pytest.fixture
def no_transports(tmp_path: Path) -> dict[str, str]:
    """An environment in which importing pymavlink, zenoh, can or dronecan raises."""
    return env_without_transports(tmp_path / "refuse")


def ftcap_hil(env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    cmd = [sys.executable, "-m", "ftcap_hil", *args]
    return subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120, check=False)


def test_the_refuser_does_refuse(no_transports: dict[str, str]) -> None:
    for name in (*TRANSPORTS, "can.interfaces"):
        code = f"import {name}"
        done = subprocess.run(
            [sys.executable, "-c", code], env=no_transports, capture_output=True, text=True
        )
        assert done.returncode != 0 and "refused in this test" in done.stderr, name


@pytest.mark.parametrize(
    ("command", "option"), [("simulate", "--integrator"), ("campaign", "--scheduler")]
)
def test_help_works_without_the_transports(
    no_transports: dict[str, str], command: str, option: str
) -> None:
    done = ftcap_hil(no_transports, command, "--help")
    assert done.returncode == 0, done.stderr
    assert option in done.stdout and "--out" in done.stdout


def test_simulate_runs_without_the_transports(
    no_transports: dict[str, str], tmp_path: Path
) -> None:
    out = tmp_path / "run"
    done = ftcap_hil(
        no_transports, "simulate", "paper-4.1", "--mode", "ftcap", "--out", str(out),
        "--no-plots", "--quiet",
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    results = json.loads((out / "results.json").read_text())
    assert "ftcap" in json.dumps(results)
    assert (out / "ftcap" / "timeseries.csv").stat().st_size > 1000


def test_the_top_help_lists_every_command_and_imports_none() -> None:
    code = (
        "import sys\nfrom ftcap_hil.apps import cli\n"
        "try:\n    cli.main(['--help'])\nexcept SystemExit:\n    pass\n"
        "print('MODULES', sorted(m for m in sys.modules if m.startswith('ftcap_hil.apps.')))"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True
    )
    help_text, _, modules = done.stdout.partition("MODULES ")
    for name in ("simulate", "campaign", "allocator", "sim", "gcs", "demo", "can-hub"):
        assert f"    {name} " in help_text, name
    assert "Offline closed-loop simulation of a scenario" in help_text
    assert modules.strip() == "['ftcap_hil.apps.cli']"


@pytest.mark.parametrize(
    ("argv", "command"),
    [
        (["simulate", "paper-4.1"], "simulate"),
        (["-vv", "can-hub", "--port", "0"], "can-hub"),
        (["--verbose", "gcs"], "gcs"),
        (["--help"], None),
        (["nope", "simulate"], None),
        ([], None),
    ],
)
def test_the_command_is_the_first_word_that_is_no_option(
    argv: list[str], command: str | None
) -> None:
    assert cli.command_of(argv) == command


def test_an_unknown_command_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as e:
        cli.main(["nope"])
    assert e.value.code == 2
    assert "invalid choice: 'nope'" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("name", "required"), [("allocator", []), ("sim", []), ("gcs", ["--mission", "m"])]
)
def test_the_set_option_is_one_declaration_for_three_commands(
    name: str, required: list[str]
) -> None:
    parser = cli.build_parser(name)
    args = parser.parse_args([name, *required, "--set", "a.b=1", "--set", "c.d=[2]"])
    assert args.set == ["a.b=1", "c.d=[2]"]
    assert parser.parse_args([name, *required]).set == []
