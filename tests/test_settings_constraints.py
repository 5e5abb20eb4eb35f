"""quatmotion._settings: the light Interval/StrOptions agree with scikit-learn's, which is
imported only for a value that is not plainly valid."""

from __future__ import annotations

import math
from numbers import Integral, Real

import numpy as np
import pytest
from sklearn.utils._param_validation import Interval as SkInterval
from sklearn.utils._param_validation import StrOptions as SkStrOptions

from quatmotion._settings import Interval, StrOptions, _quick_check

VALUES = [0, 1, 2, -1, 0.0, 0.5, 1.0, 2.5, -0.5, math.inf, -math.inf, math.nan, True, False,
          np.int64(3), np.float32(0.5), "cm", "mm", "", None, (1,), 10**30]  # fmt: skip


@pytest.mark.parametrize(
    "light",
    [
        Interval(Integral, 1, None, closed="left"),
        Interval(Real, 0, None, closed="neither"),
        Interval(Real, 1.0, 1000.0, closed="both"),
        Interval(Real, None, 0, closed="right"),
        Interval(Integral, -1, 1, closed="neither"),
    ],
)
def test_a_light_interval_accepts_only_what_scikit_learns_accepts(light):
    full = SkInterval(light.type, light.left, light.right, closed=light.closed)
    assert isinstance(light.sklearn(), SkInterval)
    for value in VALUES:
        if light.satisfied(value):
            assert full.is_satisfied_by(value), (light, value)
        elif isinstance(value, light.type) and not isinstance(value, bool) and value == value:
            assert not full.is_satisfied_by(value), (light, value)  # out of range for both


def test_light_str_options_and_the_plain_forms():
    light = StrOptions({"cm", "mm"})
    full = SkStrOptions({"cm", "mm"})
    for value in VALUES:
        assert bool(light.satisfied(value)) == full.is_satisfied_by(value)
    assert _quick_check(None, None) and _quick_check("boolean", False)
    assert _quick_check(str, "x") and _quick_check(tuple, (1,))
    assert _quick_check(None, 0) is None and _quick_check("boolean", 1) is None
    assert _quick_check(Real, 1.0) is None  # abstract numbers: scikit-learn decides


def test_an_invalid_value_gets_scikit_learns_message():
    from quatmotion.collection import ReadSettings
    from quatmotion.retrieval.index import IndexSettings

    with pytest.raises(ValueError, match=r"'batch' parameter of IndexSettings must be an int"):
        IndexSettings(batch=0)
    with pytest.raises(ValueError, match=r"'units' parameter of ReadSettings"):
        ReadSettings(units=-2.0)
    assert ReadSettings(units=2.54).units == 2.54 and ReadSettings(units="mm").units == "mm"
