"""``[zenoh] ros2``, ``domain_id`` and ``namespace`` of the allocator's and the vessel's files."""

from __future__ import annotations

import re

import pytest

from ftcap_hil.config.daemon import load_daemon_config
from ftcap_hil.config.sim import load_config
from ftcap_hil.core.errors import ConfigError


def test_off_by_default() -> None:
    zenoh = load_daemon_config(None, []).ports.zenoh
    assert zenoh is not None and (zenoh.ros2, zenoh.domain_id, zenoh.namespace) == (False, 0, "")


def test_switched_on_in_both_files() -> None:
    keys = ["zenoh.ros2=true", "zenoh.domain_id=42", 'zenoh.namespace="/fleet/a"']
    for zenoh in (load_daemon_config(None, keys).ports.zenoh, load_config(None, keys).ports.zenoh):
        assert zenoh is not None and (zenoh.ros2, zenoh.domain_id, zenoh.namespace) == (
            True, 42, "/fleet/a",
        )  # fmt: skip


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("zenoh.domain_id=233", "allocator.toml: [zenoh] domain_id: expected an integer in 0..232"),
        ('zenoh.namespace="fleet"', "allocator.toml: [zenoh] namespace: ROS namespace 'fleet'"),
        ("zenoh.ros2=1", "allocator.toml: [zenoh] ros2: expected true or false, got 1"),
        ("zenoh.domian_id=1", "[zenoh] unknown key 'domian_id' (did you mean 'domain_id'?)"),
    ],
)
def test_bad_values_name_the_file_table_and_key(override: str, message: str) -> None:
    with pytest.raises(ConfigError, match=re.escape(message)):
        load_daemon_config(None, [override])
