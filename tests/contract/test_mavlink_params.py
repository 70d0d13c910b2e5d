"""The parameter table rules of bridges.mavlink.params (pure, no sockets)."""

from __future__ import annotations

import math

import pytest

from bridges.mavlink.errors import LinkConfigError
from bridges.mavlink.params import ParamServer, ParamSpec, ParamType


def _server() -> ParamServer:
    return ParamServer(
        [
            ParamSpec("GAIN", 0.5, min=0.0, max=1.0),
            ParamSpec("COUNT", 3, ParamType.INT, 1, 8, settable_while_running=False),
            ParamSpec("ODD", 1, ParamType.INT, validate=lambda v: None if v % 2 else "even"),
        ]
    )


def test_defaults_indices_and_values() -> None:
    server = _server()
    assert len(server) == 3
    assert server.values() == {"GAIN": 0.5, "COUNT": 3.0, "ODD": 1.0}
    assert (server.index_of("COUNT"), server.index_of("NOPE")) == (1, None)
    assert server.get_index(2) == 1.0


def test_accepted_set_bumps_generation() -> None:
    server = _server()
    result = server.set("GAIN", 0.75)
    assert (result.accepted, result.value, server.get("GAIN"), server.generation) == (
        True,
        0.75,
        0.75,
        1,
    )


@pytest.mark.parametrize(
    ("name", "value", "running", "reason"),
    [
        ("GAIN", 1.5, False, "outside [0, 1]"),
        ("GAIN", math.inf, False, "not finite"),
        ("COUNT", 2.5, False, "not an integer"),
        ("COUNT", 5, True, "not settable while running"),
        ("ODD", 4, False, "even"),
        ("ODD", 2.0**25, False, "not an integer within"),
    ],
)
def test_refused_set_keeps_the_value_and_says_why(name, value, running, reason) -> None:
    server = _server()
    server.set_running(running)
    before = server.get(name)
    result = server.set(name, value)
    assert not result.accepted
    assert result.value == before == server.get(name)
    assert reason in result.reason
    assert server.generation == 0


def test_settable_while_running_only_matters_while_running() -> None:
    server = _server()
    server.set_running(True)
    assert server.set("GAIN", 0.1).accepted
    server.set_running(False)
    assert server.set("COUNT", 5).accepted


@pytest.mark.parametrize(
    ("specs", "message"),
    [
        ([ParamSpec("A_NAME_LONGER_THAN_16", 0.0)], "A_NAME_LONGER_THAN_16"),
        ([ParamSpec("lower", 0.0)], "lower"),
        ([ParamSpec("X", 0.0), ParamSpec("X", 1.0)], "duplicate"),
        ([ParamSpec("X", 2.0, max=1.0)], "params.X: default 2"),
        ([ParamSpec("N", 0.5, ParamType.INT)], "params.N"),
    ],
)
def test_bad_tables_fail_at_start_naming_the_param(specs, message) -> None:
    with pytest.raises(LinkConfigError, match=message):
        ParamServer(specs)
