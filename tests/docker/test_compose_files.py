"""The compose reader of the docker tests (compose_files.py) follows Compose: interpolation,
string commands, ``--set`` keys checked against the shipped configs."""

from __future__ import annotations

import pytest

from tests.docker.compose_files import (
    COMPOSE,
    argv_of,
    gcs_mission,
    interpolate,
    load_compose,
    read_image,
    unknown_set_keys,
)


def test_a_set_key_the_product_does_not_know_is_reported() -> None:
    argv = ["ftcap-hil", "allocator", "--set", "can.chanel=127.0.0.1:1", "--set", "can.channel=x"]
    assert unknown_set_keys(argv) == ["allocator: --set can.chanel=127.0.0.1:1"]
    gcs = ["ftcap-hil", "gcs", "--set", "gcs.wrench_limit=[1,1,1]", "--set", "gcs.nope=1"]
    assert unknown_set_keys(gcs) == ["gcs: --set gcs.nope=1"]


def test_interpolation_and_string_commands_follow_compose() -> None:
    env = {"SET": "x", "EMPTY": ""}
    assert (
        interpolate("${SET:-d} ${EMPTY:-d} ${EMPTY-d} ${UNSET-d} $$ ${SET:+y}", env) == "x d  d $ y"
    )
    with pytest.raises(ValueError, match="need it"):
        interpolate("${UNSET:?need it}", env)
    assert argv_of('gcs --set "a=[1, 2]" ') == ["gcs", "--set", "a=[1, 2]"]
    compose = load_compose(COMPOSE, env={"FTCAP_GCS_ARGS": "--duration 30", "FTCAP_MISSION": "m"})
    mission, argv = gcs_mission(compose, read_image())
    assert mission == "m" and argv[-2:] == ["--duration", "30"]
