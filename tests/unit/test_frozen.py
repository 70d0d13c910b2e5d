"""core/frozen.py: a frozen dataclass with fast_init's __init__ is the same instance."""

from __future__ import annotations

import dataclasses
import pickle
from dataclasses import dataclass, field

import numpy as np
import pytest

from ftcap_hil.core.estimation.config import Estimate
from ftcap_hil.core.frozen import fast_init


@dataclass(frozen=True)
class Reference:
    a: int
    d: float
    c: float = 0.5
    items: list[int] = field(default_factory=list)


@fast_init
@dataclass(frozen=True)
class Fast:
    a: int
    d: float
    c: float = 0.5
    items: list[int] = field(default_factory=list)


@pytest.mark.parametrize(
    ("args", "kwargs"),
    [
        ((1, 2.0), {}),
        ((1, 2.0, 3.0), {}),
        ((1,), {"d": 2.0, "items": [4]}),
        ((), {"a": 7, "d": 0.0}),
    ],
)
def test_the_instance_is_the_dataclasses_own(args: tuple, kwargs: dict) -> None:
    fast, ref = Fast(*args, **kwargs), Reference(*args, **kwargs)
    assert dataclasses.asdict(fast) == dataclasses.asdict(ref)
    assert repr(fast).replace("Fast", "Reference") == repr(ref)
    assert fast == Fast(*args, **kwargs) and pickle.loads(pickle.dumps(fast)) == fast
    assert dataclasses.replace(fast, c=9.0).c == 9.0 and fast.c == ref.c
    with pytest.raises(dataclasses.FrozenInstanceError):
        fast.a = 3  # type: ignore[misc]


def test_each_default_factory_call_is_a_new_object() -> None:
    assert Fast(1, 2.0).items is not Fast(1, 2.0).items


def test_missing_arguments_fail_as_the_dataclasses_own() -> None:
    with pytest.raises(TypeError):
        Fast(1)


def test_a_class_it_cannot_serve_is_refused() -> None:
    @dataclass(frozen=True)
    class Checked:
        a: int

        def __post_init__(self) -> None:
            pass

    @dataclass
    class Mutable:
        a: int

    @dataclass(frozen=True)
    class Clash:
        _fields_: int

    for cls in (Checked, Mutable, Clash, int):
        with pytest.raises(TypeError):
            fast_init(cls)


def test_a_core_result_keeps_its_defaults() -> None:
    d = np.array([1.0, 0.5])
    est = Estimate(d, np.zeros(3), np.zeros(2))
    assert est.innovation == 0.0 and est.window_len == 0 and not est.restarted
    assert est.delta_std is None and est.delta_hat is d
    assert dataclasses.replace(est, window_len=3).window_len == 3
