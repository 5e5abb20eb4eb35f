"""quatmotion._settings: the parameter constraints every settings class and estimator declares,
checked without scikit-learn's private validation module."""

from __future__ import annotations

import math
import re
from numbers import Integral, Real
from pathlib import Path

import numpy as np
import pytest

import quatmotion
from quatmotion._settings import Interval, StrOptions, validate_parameters


@pytest.mark.parametrize(
    ("interval", "inside", "outside"),
    [
        (Interval(Integral, 1, None, closed="left"), [1, 2, np.int64(3), 10**30],
         [0, -1, 1.0, 0.5, True, math.nan, math.inf, "1", None]),
        (Interval(Real, 0, None, closed="neither"), [0.5, 1, 2.5, np.float32(0.5), 10**30],
         [0, 0.0, -0.5, math.inf, math.nan, False, "cm", None]),
        (Interval(Real, 1.0, 1000.0, closed="both"), [1, 1.0, 1000, 500.5],
         [0.999, 1000.001, math.nan, True]),
        (Interval(Real, None, 0, closed="right"), [0, -1.5, -(10**30)],
         [0.001, math.inf, -math.inf, math.nan]),
        (Interval(Integral, -1, 1, closed="neither"), [0], [-1, 1, 0.0, False]),
    ],
)  # fmt: skip
def test_an_interval_holds_its_numbers_and_nothing_else(interval, inside, outside):
    for value in inside:
        assert interval.satisfied(value), (interval, value)
    for value in outside:
        assert not interval.satisfied(value), (interval, value)


def test_an_interval_says_its_range_as_scikit_learn_does():
    assert str(Interval(Integral, 1, None, closed="left")) == "an int in the range [1, inf)"
    assert str(Interval(Real, 0, 2, closed="neither")) == "a float in the range (0, 2)"
    with pytest.raises(TypeError):
        Interval(float, 0, 1, closed="both")
    with pytest.raises(ValueError):
        Interval(Real, 0, 1, closed="open")


def test_str_options_and_the_plain_forms():
    options = StrOptions({"cm", "mm"})
    assert options.satisfied("cm") and not options.satisfied("m") and not options.satisfied(None)
    constraints = {
        "a": [None, "boolean"],
        "b": ["random_state"],
        "c": [tuple],
    }
    validate_parameters(constraints, {"a": None, "b": 3, "c": (1,)}, "X")
    validate_parameters(constraints, {"a": np.True_, "b": np.random.RandomState(0), "c": ()}, "X")
    for bad in ({"a": 1}, {"b": -1}, {"b": 2**32}, {"b": 1.0}, {"c": [1]}):
        with pytest.raises(ValueError, match=rf"The '{next(iter(bad))}' parameter of X must be"):
            validate_parameters(constraints, bad, "X")


def test_an_invalid_value_is_named_with_its_range_and_value():
    from quatmotion.collection import ReadSettings
    from quatmotion.retrieval.index import IndexSettings

    with pytest.raises(
        ValueError,
        match=r"The 'batch' parameter of IndexSettings must be an int in the range \[1, inf\)\. "
        r"Got 0 instead\.",
    ):
        IndexSettings(batch=0)
    with pytest.raises(ValueError, match=r"'units' parameter of ReadSettings must be None, a flo"):
        ReadSettings(units=-2.0)
    assert ReadSettings(units=2.54).units == 2.54 and ReadSettings(units="mm").units == "mm"


def test_an_estimator_checks_its_parameters_at_fit():
    from quatmotion.sparse import QSSD

    Y = np.tile(np.array([1.0, 0.0, 0.0, 0.0]), (4, 2, 1))
    with pytest.raises(ValueError, match="'n_atoms' parameter of QSSD must be an int"):
        QSSD(n_atoms=0).fit(Y)
    with pytest.raises(ValueError, match="'refit' parameter of QSSD must be a str among"):
        QSSD(refit="sometimes").fit(Y)


def test_no_module_imports_a_private_scikit_learn_name():
    # Any scikit-learn release may move or change its private modules and names.
    package = Path(quatmotion.__file__).parent
    private = re.compile(
        r"(from|import)\s+sklearn(\.\w+)*\._\w+|from\s+sklearn\S*\s+import\s+.*\b_\w+"
    )
    offenders = [
        f"{path.relative_to(package)}:{n}"
        for path in sorted(package.rglob("*.py"))
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
        if private.search(line)
    ]
    assert offenders == []
