"""The option toolkit (``core/host/options.py``): what each check accepts, what it returns, and the
one-line message naming the key for each refusal."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hapticlab.core.errors import ConfigError
from hapticlab.core.host.options import (
    OptionError,
    accepts,
    boolean,
    check,
    check_fields,
    choice,
    integer,
    is_number,
    matrix,
    number,
    read_table,
    text,
    unknown_key,
    vector,
)


def refusal(function, *args, **kwargs) -> str:
    """The message of the OptionError a check raises (one line, naming the key)."""
    with pytest.raises(OptionError) as excinfo:
        function(*args, **kwargs)
    message = str(excinfo.value)
    assert "\n" not in message and isinstance(excinfo.value, ValueError)
    return message


@pytest.mark.parametrize(
    ("value", "expected"),
    [(1, True), (1.5, True), (-0.0, True), (math.inf, True), (np.float64(2.0), True), (np.int64(3), True)]
    + [(True, False), (False, False), (math.nan, False), ("1", False), (None, False), ([1], False)],
)
def test_is_number(value, expected):
    assert is_number(value) is expected


def test_number_converts_to_float():
    assert number("k", 2) == 2.0 and type(number("k", 2)) is float
    assert type(number("k", np.float32(0.5))) is float
    assert number("k", -1e300) == -1e300


@pytest.mark.parametrize("value", [True, False, math.nan, "1.5", None, [1.0], math.inf, -math.inf])
def test_number_refuses_what_is_not_a_finite_number(value):
    assert refusal(number, "gain", value) == f"gain: must be a finite number, got {value!r}"


def test_number_infinite_only_when_allowed():
    assert number("k", math.inf, finite=False) == math.inf
    assert refusal(number, "k", math.nan, finite=False) == "k: must be a number, got nan"
    assert refusal(number, "k", True, finite=False) == "k: must be a number, got True"
    assert refusal(number, "k", -math.inf, minimum=0, finite=False) == "k: must be a number >= 0, got -inf"


def test_number_limits_inclusive_and_exclusive():
    assert number("k", 0, minimum=0) == 0.0 and number("k", 1, maximum=1) == 1.0
    assert refusal(number, "k", 0, above=0) == "k: must be a finite number > 0, got 0"
    assert refusal(number, "k", 1, below=1) == "k: must be a finite number < 1, got 1"
    assert refusal(number, "k", -0.1, minimum=0) == "k: must be a finite number >= 0, got -0.1"
    assert refusal(number, "k", 2, maximum=1) == "k: must be a finite number <= 1, got 2"
    message = refusal(number, "rate", 3e9, above=0, maximum=1e4, hint=" (Hz)")
    assert message == "rate: must be a finite number > 0 and <= 10000 (Hz), got 3000000000.0"
    assert number("k", 0.5, above=0, below=1) == 0.5


def test_integer():
    assert integer("k", 3) == 3 and type(integer("k", np.int64(3))) is int
    assert integer("k", -1, minimum=-1, maximum=63) == -1 and integer("k", 63, minimum=-1, maximum=63) == 63
    for value in (1.0, 1.5, True, "3", None):
        assert refusal(integer, "seed", value) == f"seed: must be a whole number, got {value!r}"
    assert refusal(integer, "k", 0, minimum=1) == "k: must be a whole number >= 1, got 0"
    assert refusal(integer, "k", 100, minimum=0, maximum=99) == "k: must be a whole number >= 0 and <= 99, got 100"
    assert refusal(integer, "k", 0, minimum=1, hint=" (samples)") == "k: must be a whole number >= 1 (samples), got 0"


def test_boolean():
    assert boolean("k", True) is True and boolean("k", False) is False
    for value in (1, 0, "true", None):
        assert refusal(boolean, "on", value) == f"on: must be true or false, got {value!r}"


def test_text():
    assert text("k", "") == "" and text("k", "x") == "x"
    assert refusal(text, "name", 5) == "name: must be a string, got 5"
    assert refusal(text, "path", None, hint=" (a path)") == "path: must be a string (a path), got None"


def test_choice():
    assert choice("k", "b", ("a", "b")) == "b"
    assert refusal(choice, "mode", "c", ("a", "b")) == "mode: must be 'a' or 'b', got 'c'"
    assert refusal(choice, "mode", "c", ("a", "b", "x")) == "mode: must be 'a', 'b' or 'x', got 'c'"
    assert refusal(choice, "mode", "c", ("a",)) == "mode: must be 'a', got 'c'"
    assert refusal(choice, "n", True, (1, 2)) == "n: must be 1 or 2, got True"  # a bool is not 1
    assert refusal(choice, "n", 1, ("1", "2")) == "n: must be '1' or '2', got 1"


def test_vector_returns_a_read_only_float_array():
    array = vector("k", [1, 2, 3])
    assert array.dtype == float and array.tolist() == [1.0, 2.0, 3.0] and not array.flags.writeable
    source = np.array([1, 2, 3])
    assert vector("k", source).tolist() == [1.0, 2.0, 3.0] and source.flags.writeable  # a copy
    assert vector("k", (0.5, 0.5), size=2).tolist() == [0.5, 0.5]
    assert vector("k", 0.1, broadcast=True).tolist() == [0.1, 0.1, 0.1]
    assert vector("k", [0, 0, 0], minimum=0).tolist() == [0.0, 0.0, 0.0]


@pytest.mark.parametrize(
    "value", [[1, 2], [1, 2, 3, 4], [1, "x", 3], [1, True, 3], [1, math.nan, 3], [1, math.inf, 3], 1.0, "abc", None]
)
def test_vector_refuses_what_is_not_three_finite_numbers(value):
    assert refusal(vector, "cog", value) == f"cog: must be 3 numbers, got {value!r}"


def test_vector_limits_and_broadcast_messages():
    assert (
        refusal(vector, "n", -0.1, broadcast=True, minimum=0) == "n: must be a number or 3 numbers, each >= 0, got -0.1"
    )
    assert refusal(vector, "s", [1, 0, 1], above=0) == "s: must be 3 numbers, each > 0, got [1, 0, 1]"
    assert refusal(vector, "v", True, broadcast=True) == "v: must be a number or 3 numbers, got True"
    assert refusal(vector, "v", math.inf, broadcast=True) == "v: must be a number or 3 numbers, got inf"
    assert refusal(vector, "r", [1, 2], hint=" (rad)") == "r: must be 3 numbers (rad), got [1, 2]"
    assert refusal(vector, "v", np.array([True, False, True])).startswith("v: must be 3 numbers, got array(")


def test_matrix():
    m = matrix("k", [[1, 0, 0], [0, 1, 0], [0, 0, 1]])
    assert np.array_equal(m, np.eye(3)) and m.dtype == float and not m.flags.writeable
    assert np.array_equal(matrix("k", np.eye(2), shape=(2, 2)), np.eye(2))
    for value in ([[1, 0, 0], [0, 1, 0]], [[1, 0, 0], [0, "x", 0], [0, 0, 1]], [[1, 0, 0], [0, 1], [0, 0, 1]], 1.0):
        assert refusal(matrix, "G", value) == f"G: must be a 3x3 matrix (3 rows of 3 numbers), got {value!r}"
    assert refusal(matrix, "G", [[math.nan] * 3] * 3).startswith("G: must be a 3x3 matrix")
    assert refusal(matrix, "G", [[True] * 3] * 3).startswith("G: must be a 3x3 matrix")


def test_accepts_says_what_a_check_takes():
    assert accepts(number) == "a finite number"
    assert accepts(check(number, above=0, maximum=1, hint=" (s)")) == "a finite number > 0 and <= 1 (s)"
    assert accepts(check(integer, minimum=0)) == "a whole number >= 0"
    assert accepts(boolean) == "true or false"
    assert accepts(text) == "a string"
    assert accepts(check(choice, choices=("a", "b"))) == "'a' or 'b'"
    assert accepts(check(vector, broadcast=True, minimum=0)) == "a number or 3 numbers, each >= 0"
    assert accepts(matrix) == "a 3x3 matrix (3 rows of 3 numbers)"
    with pytest.raises(TypeError):
        accepts(lambda key, value: value)


def test_option_error_under_names_the_table():
    error = OptionError("mass", "must be a finite number > 0, got -1")
    assert str(error) == "mass: must be a finite number > 0, got -1" and error.key == "mass"
    under = error.under("world.tool")
    assert isinstance(under, ConfigError) and str(under) == "world.tool.mass: must be a finite number > 0, got -1"
    assert str(error.under("")) == str(error)


def test_unknown_key():
    error = unknown_key("world.sensor", "noise_forse", ["noise_force", "noise_torque", "bias_force"])
    assert isinstance(error, ConfigError)
    assert str(error) == (
        "world.sensor.noise_forse: unknown option; did you mean noise_force?; "
        "known options: bias_force, noise_force, noise_torque"
    )
    assert str(unknown_key("", "zzz", [])) == "zzz: unknown option; known options: none"


def test_read_table():
    checks = {"mass": check(number, above=0), "seed": check(integer, minimum=0), "on": boolean}
    assert read_table("t", {"mass": 2, "on": True}, checks) == {"mass": 2.0, "on": True}
    assert read_table("t", {}, checks) == {}
    with pytest.raises(ConfigError, match=r"^t\.mass: must be a finite number > 0, got 0$"):
        read_table("t", {"mass": 0}, checks)
    with pytest.raises(
        ConfigError, match=r"^t\.mas: unknown option; did you mean mass\?; known options: mass, on, seed$"
    ):
        read_table("t", {"mas": 1}, checks)
    with pytest.raises(ConfigError, match=r"^t: must be a table, got 3$"):
        read_table("t", 3, checks)


def test_check_fields_converts_a_frozen_records_fields():
    from dataclasses import dataclass

    @dataclass(frozen=True)
    class Record:
        mass: float = 1
        cog: tuple = (0, 0, 0)

        def __post_init__(self):
            check_fields(self, {"mass": check(number, above=0), "cog": vector})

    record = Record()
    assert type(record.mass) is float and record.cog.tolist() == [0.0, 0.0, 0.0]
    assert refusal(Record, mass=0) == "mass: must be a finite number > 0, got 0"
