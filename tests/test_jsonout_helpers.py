"""The two dict helpers of :mod:`chatterspec.jsonout` behind the results' ``to_dict``/``describe``."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from chatterspec.jsonout import fields_dict, finite_or_none
from chatterspec.plants.closed_loop import PIDController
from chatterspec.studies.intervals import RateEstimate


@dataclass(frozen=True)
class _Pair:
    b: int
    a: tuple[float, ...]

    @property
    def total(self) -> float:
        return self.b + sum(self.a)


def test_fields_dict_keeps_declaration_or_given_order_and_values_as_they_are() -> None:
    p = _Pair(2, (0.5, 1.5))
    assert list(fields_dict(p).items()) == [("b", 2), ("a", (0.5, 1.5))]  # declaration order, no conversion
    assert list(fields_dict(p, ("total", "b")).items()) == [("total", 4.0), ("b", 2)]  # properties too
    d = fields_dict(p)
    d["extra"] = 1  # a new dict each call
    assert "extra" not in fields_dict(p)


def test_fields_dict_without_names_needs_a_dataclass() -> None:
    with pytest.raises(TypeError):
        fields_dict(object())
    with pytest.raises(AttributeError):
        fields_dict(_Pair(1, ()), ("missing",))


def test_to_dicts_built_with_fields_dict() -> None:
    pid = PIDController(2.0, 0.5, 300.0, kd=0.1)
    assert list(pid.to_dict()) == [
        "kp", "ki", "saturation", "kd", "derivative_filter_s", "anti_windup", "tracking_time_s",
        "setpoint_weight",
    ]  # fmt: skip
    assert PIDController(**pid.to_dict()) == pid  # the constructor's arguments
    r = RateEstimate(3, 100, 0.99).to_dict()
    assert list(r) == ["rate", "ci_low", "ci_high", "count", "trials", "effective_trials"]
    assert r["rate"] == 0.03 and r["ci_low"] < 0.03 < r["ci_high"] and r["effective_trials"] == 100.0


@pytest.mark.parametrize(
    ("value", "expected"),
    [(0.25, 0.25), (np.float32(0.5), 0.5), (3, 3.0), (math.nan, None), (-math.inf, None), (np.inf, None)],
)
def test_finite_or_none(value: float, expected: float | None) -> None:
    out = finite_or_none(value)
    assert out == expected and (out is None or type(out) is float)
