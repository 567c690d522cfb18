"""``core.types.record``: the per-tick records keep the frozen dataclass's behaviour with a quicker ``__init__``."""

from __future__ import annotations

import dataclasses
import inspect
import pickle

import numpy as np
import pytest

from hapticlab.core import types
from hapticlab.core.types import record

RECORDS = [
    types.WrenchSample,
    types.WrenchBlock,
    types.PoseSample,
    types.AlignedSamples,
    types.Estimates,
    types.HapticCommand,
    types.DeviceState,
    types.RobotTarget,
]


def _reference(cls):
    """The same fields as a plain ``@dataclass(frozen=True, slots=True)`` (the dataclass's own ``__init__``)."""
    spec = [
        (f.name, f.type, dataclasses.field(default=f.default))
        if f.default is not dataclasses.MISSING
        else (f.name, f.type)
        for f in dataclasses.fields(cls)
    ]
    return dataclasses.make_dataclass(cls.__name__, spec, frozen=True, slots=True)


@pytest.mark.parametrize("cls", RECORDS, ids=lambda c: c.__name__)
def test_a_record_is_built_and_behaves_as_the_frozen_dataclass(cls):
    reference = _reference(cls)
    assert str(inspect.signature(cls)) == str(inspect.signature(reference))
    required = [f.name for f in dataclasses.fields(cls) if f.default is dataclasses.MISSING]
    values = {name: np.arange(3.0) + k for k, name in enumerate(required)}
    for made, want in ((cls(**values), reference(**values)), (cls(*values.values()), reference(*values.values()))):
        for f in dataclasses.fields(cls):  # every field set, the defaults filled in
            got, expected = getattr(made, f.name), getattr(want, f.name)
            assert got is expected or (got is None and expected is None), f.name
    made = cls(*values.values())
    name = required[0]
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(made, name, 0)
    changed = dataclasses.replace(made, **{name: np.ones(2)})
    assert getattr(changed, name).shape == (2,) and getattr(made, name) is values[name]
    again = pickle.loads(pickle.dumps(made))
    assert all(np.array_equal(getattr(again, n), values[n]) for n in required)
    with pytest.raises(TypeError):
        cls(*values.values(), *range(len(dataclasses.fields(cls))))  # too many arguments
    if len(required) > 1:
        with pytest.raises(TypeError):
            cls(values[required[0]])  # too few


def test_a_default_factory_is_refused():
    with pytest.raises(TypeError, match="default_factory"):

        @record
        class WithFactory:
            data: dict = dataclasses.field(default_factory=dict)


def test_a_wrench_block_splits_at_the_readings_due():
    """What a sensor hands over by ``until_ns`` and what it keeps: none due, some, all; an empty block stays one."""
    block = types.WrenchBlock(
        np.array([10, 20, 30], dtype=np.int64), np.ones((3, 3)), np.zeros((3, 3)), np.arange(3), np.zeros(3, int)
    )
    for until_ns, due_t in ((9, []), (10, [10]), (25, [10, 20]), (30, [10, 20, 30]), (99, [10, 20, 30])):
        due, rest = block.split(until_ns)
        assert due.t_ns.tolist() == due_t and rest.t_ns.tolist() == [t for t in (10, 20, 30) if t not in due_t]
        assert due.seq.tolist() == [t // 10 - 1 for t in due_t]
    due, rest = types.NO_WRENCHES.split(99)
    assert not len(due) and not len(rest)
