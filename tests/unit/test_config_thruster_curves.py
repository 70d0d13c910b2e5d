"""``[can]`` thruster curves and ESC stream keys: read strictly, named in every error, and
carried into the port settings and the allocator's thruster limits."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from ftcap_hil.config.bridges import allocator_ports_from, vessel_ports_from
from ftcap_hil.config.daemon import load_daemon_config
from ftcap_hil.config.tables import Table
from ftcap_hil.config.thruster_curves import load_curve, shipped_curves
from ftcap_hil.config.toml import parse_toml
from ftcap_hil.core.errors import ConfigError


def _root(text: str) -> Table:
    return Table(parse_toml(text, "f.toml"), "f.toml")


def raises(message: str) -> pytest.RaisesContext[ConfigError]:
    return pytest.raises(ConfigError, match=re.escape(message))


def test_shipped_curves_load() -> None:
    assert {"t200-12v", "t200-12v-linear"} <= set(shipped_curves())
    t200 = load_curve("t200-12v")
    assert (t200.thrust_max_n, t200.thrust_min_n) == (36.4, -28.6)
    assert float(t200.thrust(0.5)) == pytest.approx(12.23)


def test_one_curve_for_all_scaled_to_the_model() -> None:
    root = _root('[can]\nthruster_curve = "t200-12v"\ncurve_thrust_max_n = 0.1\n')
    ports = vessel_ports_from(root, 4)
    root.finish()
    curves = ports.can.curves
    assert curves is not None and len(curves) == 4
    assert curves[0].thrust_max_n == 0.1
    assert curves[0].thrust_min_n == pytest.approx(-0.1 * 28.6 / 36.4)
    assert float(curves[0].thrust(0.5)) == pytest.approx(0.1 * 12.23 / 36.4)


def test_one_curve_per_thruster_from_a_file(tmp_path: Path) -> None:
    own = tmp_path / "push.toml"
    own.write_text('name = "push only"\nfraction = [0, 1]\nthrust_n = [0, 2.0]\n')
    root = _root(f'[can]\nthruster_curve = ["t200-12v", "{own}"]\n')
    curves = vessel_ports_from(root, 2).can.curves
    root.finish()
    assert curves is not None
    assert curves[0].reversible and not curves[1].reversible and curves[1].thrust_max_n == 2.0


def test_without_a_curve_the_map_is_linear() -> None:
    assert vessel_ports_from(_root("[can]\n"), 2).can.curves is None


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('thruster_curve = ["t200-12v"]', "thruster_curve: expected one value or 2 (one per"),
        ('thruster_curve = "nope"', "thruster_curve: thruster curve 'nope': no such file"),
        ("thruster_curve = 3", "thruster_curve: expected curve names or files, got [3, 3]"),
        ("curve_thrust_max_n = 1.0", "curve_thrust_max_n: needs thruster_curve"),
        (
            'thruster_curve = "t200-12v"\ncurve_thrust_max_n = [1, -1]',
            "curve_thrust_max_n: expected a thrust > 0 N, got -1",
        ),
        (
            'thruster_curve = "t200-12v"\ncurve_thrust_max_n = inf',
            "curve_thrust_max_n: expected a thrust > 0 N, got inf",
        ),
    ],
)
def test_bad_curve_keys_are_named(text: str, message: str) -> None:
    with raises(f"f.toml: [can] {message}"):
        vessel_ports_from(_root(f"[can]\n{text}\n"), 2)


def test_a_bad_curve_file_is_named(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\nfraction = [-1, 0, 1]\nthrust_n = [1, 0, 2]\nsorce = "typo"\n')
    with raises("[can] thruster_curve:"):
        vessel_ports_from(_root(f'[can]\nthruster_curve = "{bad}"\n'), 2)


def test_allocator_esc_stream_keys() -> None:
    root = _root("[can]\nesc_rate_hz = 200\nesc_hold_s = 0.5\nesc_command_timeout_s = 0.1\n")
    can = allocator_ports_from(root, 2).can
    root.finish()
    assert (can.esc_rate_hz, can.esc_hold_s, can.esc_command_timeout_s) == (200, 0.5, 0.1)
    off = allocator_ports_from(_root("[can]\nesc_rate_hz = 0\n"), 2).can
    assert off.esc_rate_hz == 0.0  # no stream: the hold and timeout checks do not apply
    default = allocator_ports_from(_root(""), 2).can
    assert (default.esc_rate_hz, default.esc_command_timeout_s) == (100.0, 0.2)
    assert default.node_name == "org.ftcap.allocator"


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("esc_rate_hz = 500", "can.esc_rate_hz: expected 1..400 Hz, got 500"),
        ("esc_rate_hz = 0.5", "can.esc_rate_hz: expected 1..400 Hz, got 0.5"),
        ("esc_rate_hz = -1", "[can] esc_rate_hz: expected a finite number >= 0"),
        ("esc_rate_hz = 10\nesc_hold_s = 0.05", "can.esc_hold_s: expected more than one period"),
        ("esc_rate_hz = 4", "can.esc_command_timeout_s: expected more than one period"),
        ('node_name = "bo\u00e9t"', "node_name: expected 1..80 ASCII characters"),
        (f'node_name = "{"x" * 81}"', "node_name: expected 1..80 ASCII characters"),
    ],
)
def test_bad_esc_stream_keys_are_named(text: str, message: str) -> None:
    with raises(message):
        allocator_ports_from(_root(f"[can]\n{text}\n"), 2)


def test_esc_stream_keys_are_the_allocators_only() -> None:
    with raises("[can] unknown key 'esc_rate_hz'"):
        root = _root("[can]\nesc_rate_hz = 100\n")
        vessel_ports_from(root, 2)
        root.finish()


def test_zenoh_wrench_limit_is_always_bounded() -> None:
    zenoh = allocator_ports_from(_root("[zenoh]\nwrench_limit = [1, 2, 3]\n"), 2).zenoh
    assert zenoh is not None and zenoh.wrench_limit == (1.0, 2.0, 3.0)
    default = allocator_ports_from(_root(""), 2).zenoh
    assert default is not None and default.wrench_limit == (1000.0, 1000.0, 1000.0)
    vessel = vessel_ports_from(_root(""), 2).zenoh
    assert vessel is not None and vessel.wrench_limit is None


def test_the_allocator_never_asks_more_than_its_curves_give() -> None:
    loaded = load_daemon_config(
        None, ["can.thruster_curve='t200-12v'", "can.curve_thrust_max_n=0.05"]
    )
    ths = loaded.daemon.thrusters
    assert list(ths.u_max) == [0.05] * 4  # the vessel file says 0.1 N
    assert list(ths.u_min) == pytest.approx([-0.05 * 28.6 / 36.4] * 4)


def test_the_esc_hold_outlasts_a_few_daemon_periods() -> None:
    shipped = load_daemon_config(None, ["can.esc_hold_s=0.25"])  # 3.54 Hz: 0.71 s at least
    assert shipped.ports.can.esc_hold_s == pytest.approx(2.5 * 0.2827, rel=1e-3)
    assert load_daemon_config(None).ports.can.esc_hold_s == 1.0
    slow = load_daemon_config(None, ["daemon.rate_hz=0.5"])
    assert slow.ports.can.esc_hold_s == 5.0
