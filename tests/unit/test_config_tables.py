"""The strict table reader: typed getters, and errors that name the file, table and key."""

from __future__ import annotations

import enum
import re
from dataclasses import dataclass

import numpy as np
import pytest

from ftcap_hil.config.table_dataclass import read_dataclass
from ftcap_hil.config.tables import Table, nearest
from ftcap_hil.config.toml import parse_toml
from ftcap_hil.core.errors import ConfigError, ExitCode


class Colour(enum.Enum):
    RED = "red"
    GREEN = "green"
    BLUE = "blue"


@dataclass(frozen=True)
class Tunables:
    gain: float = 1.0
    window: int = 20
    on: bool = True
    backend: str = "a"
    colour: Colour = Colour.RED
    limit: float | None = None

    def __post_init__(self) -> None:
        if self.window < 2:
            raise ValueError(f"window: need >= 2, got {self.window}")


def table(text: str, name: str = "t") -> Table:
    """The sub-table [name] of a TOML text, in a file called 'f.toml'."""
    return Table(parse_toml(text, "f.toml"), "f.toml").table(name)


def raises(pattern: str) -> pytest.RaisesContext[ConfigError]:
    return pytest.raises(ConfigError, match=re.escape(pattern))


def test_typed_getters_return_typed_values_and_defaults() -> None:
    t = table('[t]\nx = 2\ny = 0.5\nn = 3\nb = false\ns = "hi"\nv = [1, 2.5]\nc = "blue"\n')
    assert t.number("x") == 2.0 and isinstance(t.number("x"), float)
    assert t.number("y", lo=0.0, hi=1.0) == 0.5
    assert t.number("absent", 7.0) == 7.0 and t.number("absent2", None) is None
    assert t.integer("n", lo=1) == 3 and t.integer("no_n", 4) == 4
    assert t.boolean("b") is False and t.boolean("no_b", True) is True
    assert t.string("s") == "hi" and t.string("no_s", None) is None
    np.testing.assert_array_equal(t.vector("v", 2), [1.0, 2.5])
    assert t.enum("c", Colour) is Colour.BLUE
    assert t.choice("no_c", ["p", "q"], "q") == "q"
    t.finish()


@pytest.mark.parametrize(
    ("text", "read", "message"),
    [
        (
            "x = -1",
            lambda t: t.number("x", positive=True),
            "[t] x: expected a finite number > 0, got -1",
        ),
        (
            "x = 2",
            lambda t: t.number("x", lo=0.0, hi=1.0),
            "[t] x: expected a finite number in 0..1, got 2",
        ),
        ('x = "1"', lambda t: t.number("x"), "[t] x: expected a finite number, got '1'"),
        ("x = true", lambda t: t.number("x"), "[t] x: expected a finite number, got True"),
        ("x = nan", lambda t: t.number("x"), "[t] x: expected a finite number, got nan"),
        ("n = 2.0", lambda t: t.integer("n"), "[t] n: expected an integer, got 2.0"),
        ("n = 0", lambda t: t.integer("n", lo=1), "[t] n: expected an integer >= 1, got 0"),
        ("b = 1", lambda t: t.boolean("b"), "[t] b: expected true or false, got 1"),
        ('s = ""', lambda t: t.string("s"), "[t] s: expected a non-empty string, got ''"),
        ("v = [1, 2]", lambda t: t.vector("v", 3), "[t] v: expected 3 finite numbers, got [1, 2]"),
        (
            "v = [1, -2]",
            lambda t: t.vector("v", positive=True),
            "v: expected some finite numbers > 0",
        ),
        ("v = 1.0", lambda t: t.vector("v"), "[t] v: expected some finite numbers, got 1.0"),
        (
            "i = [1, 300]",
            lambda t: t.integers("i", 2, hi=255),
            "i: expected a list of 2 integers <= 255",
        ),
        ("l = 'a'", lambda t: t.strings("l"), "[t] l: expected a list of strings, got 'a'"),
        ("u = 1", lambda t: t.table("u"), "[t] u: expected a table, got 1"),
        ("u = {a = 1}", lambda t: t.tables("u"), "[t] u: expected an array of tables [[u]]"),
        ("", lambda t: t.number("x"), "f.toml: [t] x: missing"),
        ("", lambda t: t.tables("w", required=True), "f.toml: [[t.w]] missing"),
    ],
)
def test_bad_values_name_file_table_key_value_and_form(text, read, message) -> None:
    t = table(f"[t]\n{text}\n")
    with raises(message):
        read(t)


def test_choice_names_value_choices_and_nearest() -> None:
    t = table('[t]\nbackend = "daqpp"\n')
    with raises(
        "f.toml: [t] backend: 'daqpp' is not one of 'proxqp', 'daqp' (did you mean 'daqp'?)"
    ):
        t.choice("backend", ["proxqp", "daqp"])
    with raises("'daqpp' is not one of 'red', 'blue'"):
        t.enum("backend", Colour, exclude=[Colour.GREEN])


def test_unknown_key_names_file_table_key_nearest_and_valid_keys() -> None:
    t = table("[daemon]\nrate_hzz = 1\n", "daemon")
    t.number("rate_hz", 2.0)
    t.boolean("wake", True)
    message = "f.toml: [daemon] unknown key 'rate_hzz' (did you mean 'rate_hz'?); valid keys: "
    with raises(message + "rate_hz, wake"):
        t.finish()


def test_unknown_key_with_nothing_close_lists_the_valid_keys() -> None:
    t = table("[t]\nzzz = 1\n")
    t.number("rate_hz", 2.0)
    with raises("f.toml: [t] unknown key 'zzz'; valid keys: rate_hz"):
        t.finish()


def test_unknown_key_in_an_array_of_tables_names_the_entry() -> None:
    root = Table(
        parse_toml("[[fault]]\nfrom = 1.0\n[[fault]]\nfrom = 2.0\nuntill = 3.0\n", "s"), "s.toml"
    )
    for f in root.tables("fault"):
        f.number("from")
        f.number("until", None)
    with raises(
        "s.toml: [[fault]][1] unknown key 'untill' (did you mean 'until'?); valid keys: from, until"
    ):
        root.finish()


def test_unknown_table_at_the_top_of_a_file() -> None:
    root = Table(parse_toml("[scenario]\n[noize]\nstate_std = 1\n", "s"), "s.toml")
    root.table("scenario")
    root.table("noise")
    with raises(
        "s.toml: unknown table 'noize' (did you mean 'noise'?); valid tables: noise, scenario"
    ):
        root.finish()


def test_nested_table_names_carry_the_path() -> None:
    root = Table(parse_toml("[vessel]\n[[vessel.thruster]]\nx = 1\ny = 2\n", "v"), "v.toml")
    (th,) = root.table("vessel").tables("thruster")
    th.number("x")
    with raises("v.toml: [[vessel.thruster]][0] unknown key 'y'"):
        root.finish()


def test_context_manager_checks_on_normal_exit_only() -> None:
    with raises("unknown key 'b'"), table("[t]\na = 1\nb = 2\n") as t:
        t.number("a")
    with pytest.raises(KeyError), table("[t]\nb = 2\n"):  # the first error wins, not 'b'
        raise KeyError("first")


def test_allow_and_value_mark_keys_as_known() -> None:
    t = table("[t]\na = 1\nb = [1, 'x']\n")
    t.allow("a")
    assert t.value("b") == [1, "x"]
    t.finish()
    assert t.unknown() == []


def test_renamed_key_and_table_name_the_new_name() -> None:
    root = Table(parse_toml("[allocation]\nbackend = 'daqp'\n", "a"), "allocator.toml")
    with raises("allocator.toml: table [allocation] is now called [allocator] (same keys)"):
        root.renamed("allocation", "allocator")
    t = table("[t]\nnode = 1\n")
    with raises("f.toml: [t] node: this key is now called 'node_id'"):
        t.renamed("node", "node_id")
    t.renamed("absent", "present")  # nothing to refuse


def test_dataclass_reads_fields_by_their_types() -> None:
    t = table('[t]\ngain = 2\nwindow = 5\non = false\ncolour = "green"\nlimit = 0.5\n')
    assert read_dataclass(t, Tunables) == Tunables(2.0, 5, False, "a", Colour.GREEN, 0.5)
    t.finish()
    assert read_dataclass(table("[t]\n"), Tunables, defaults={"window": 9}) == Tunables(window=9)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("window = 1.5", "f.toml: [t] window: expected an integer, got 1.5"),
        ("window = 1", "f.toml: [t] window: need >= 2, got 1"),  # the class's own check
        ('colour = "mauve"', "colour: 'mauve' is not one of 'red', 'green', 'blue'"),
        ('backend = "c"', "backend: 'c' is not one of 'a', 'b'"),
        ("on = 0", "[t] on: expected true or false, got 0"),
    ],
)
def test_dataclass_bad_values(text: str, message: str) -> None:
    with raises(message):
        read_dataclass(table(f"[t]\n{text}\n"), Tunables, choices={"backend": ["a", "b"]})


def test_dataclass_choices_narrow_an_enum_field_to_some_members() -> None:
    narrowed = {"colour": [Colour.RED, Colour.BLUE]}
    t = table('[t]\ncolour = "blue"\n')
    assert read_dataclass(t, Tunables, choices=narrowed).colour is Colour.BLUE
    with raises("f.toml: [t] colour: 'green' is not one of 'red', 'blue'"):
        read_dataclass(table('[t]\ncolour = "green"\n'), Tunables, choices=narrowed)


def test_dataclass_unknown_field_is_an_unknown_key() -> None:
    t = table("[t]\nwindw = 3\n")
    read_dataclass(t, Tunables, exclude=["limit"])
    with raises("[t] unknown key 'windw' (did you mean 'window'?)"):
        t.finish()
    t = table("[t]\nlimit = 3\n")
    read_dataclass(t, Tunables, exclude=["limit"])
    with raises("unknown key 'limit'"):
        t.finish()


def test_config_errors_exit_with_the_config_code() -> None:
    with pytest.raises(ConfigError) as info:
        table("[t]\n").number("x")
    assert info.value.exit_code is ExitCode.CONFIG


def test_a_missing_key_or_table_names_a_close_typo() -> None:
    root = Table(parse_toml("[dampng]\nX_u = 1.0\n[vessel]\nu_mn = 1\n", "p"), "p.toml")
    with raises("p.toml: [damping] missing ('dampng' is given: a typo?)"):
        root.table("damping", required=True)
    with raises("p.toml: [vessel] u_min: missing ('u_mn' is given: a typo?)"):
        root.table("vessel").number("u_min")
    with raises("p.toml: [[reference]] missing"):
        root.tables("reference", required=True)


def test_nearest() -> None:
    assert nearest("untill", ["from", "until", "thruster"]) == "until"
    assert nearest("qqq", ["from", "until"]) is None
