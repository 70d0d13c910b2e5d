"""The local mapping of the compose world (compose_local.py) fails loudly on what it cannot map."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.docker.compose_files import COMPOSE, load_compose, read_image
from tests.docker.compose_local import build_world


def test_a_mount_that_does_not_exist_fails_the_mapping(tmp_path: Path) -> None:
    compose = load_compose(COMPOSE)
    compose["services"]["vessel"]["volumes"] = [
        "./zenoh/nope.json5:/etc/ftcap/zenoh/client.json5:ro"
    ]
    with pytest.raises(AssertionError, match="nope.json5 does not exist"):
        build_world(compose, read_image(), tmp_path)
