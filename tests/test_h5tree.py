"""Result trees in HDF5: what is written is read back, field by field, dtype by dtype; nothing else is built."""

from __future__ import annotations

import dataclasses
import math

import h5py
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from iiwa_ident._h5tree import read_tree, write_tree
from iiwa_ident.errors import IiwaIdentError


@dataclasses.dataclass
class Leaf:
    x: float
    a: np.ndarray
    tag: str = ""


@dataclasses.dataclass
class Node:
    leaves: list
    by_key: dict
    later: int = dataclasses.field(default=0, init=False)


HERE = (__name__,)

numbers = st.one_of(st.none(), st.booleans(), st.integers(-2**62, 2**62), st.floats(allow_nan=True),
                    st.complex_numbers(allow_nan=False), st.text(max_size=8))
arrays = hnp.arrays(st.sampled_from([np.float64, np.float32, np.int64, np.complex128, np.bool_]),
                    hnp.array_shapes(min_dims=0, max_dims=3, max_side=5))
leaves = st.builds(Leaf, st.floats(allow_nan=True), arrays, st.text(max_size=5))
values = st.recursive(st.one_of(numbers, arrays, leaves),
                      lambda inner: st.one_of(st.lists(inner, max_size=4), st.tuples(inner, inner),
                                              st.dictionaries(st.one_of(st.text(max_size=4), st.integers(-9, 9)),
                                                              inner, max_size=3),
                                              st.frozensets(st.integers(-5, 5), max_size=3),
                                              st.builds(Node, st.lists(leaves, max_size=2),
                                                        st.dictionaries(st.text(max_size=3), inner, max_size=2))),
                      max_leaves=12)


def same(a, b, path="") -> None:
    assert type(a) is type(b) or (isinstance(a, np.generic) and not isinstance(a, np.ndarray)), (path, a, b)
    if dataclasses.is_dataclass(a):
        for f in dataclasses.fields(a):
            same(getattr(a, f.name), getattr(b, f.name), f"{path}.{f.name}")
    elif isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b, equal_nan=True), path
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            same(x, y, f"{path}[{i}]")
    elif isinstance(a, dict):
        assert list(a) == list(b), path
        for k in a:
            same(a[k], b[k], f"{path}[{k!r}]")
    elif isinstance(a, float) and math.isnan(a):
        assert math.isnan(b), path
    elif isinstance(a, complex):
        assert a == b or (math.isnan(a.real) and math.isnan(b.real)), path
    else:
        assert a == b, (path, a, b)


@settings(max_examples=60, deadline=None)
@given(tree=st.dictionaries(st.text(min_size=1, max_size=6), values, max_size=4))
def test_a_tree_is_read_back_as_written(tree, tmp_path_factory):
    path = tmp_path_factory.mktemp("tree") / "t.h5"
    for v in tree.values():
        if isinstance(v, Node):
            v.later = 7  # a field outside __init__ is kept too
    write_tree(path, tree)
    same(tree, read_tree(path, HERE))


def test_a_class_outside_the_named_packages_is_refused(tmp_path):
    path = tmp_path / "t.h5"
    write_tree(path, {"leaf": Leaf(1.0, np.zeros(3))})
    with pytest.raises(IiwaIdentError, match=rf"{path}: .*not a result of iiwa_ident"):
        read_tree(path, ("iiwa_ident",))
    # A file naming a class the packages do not hold, or something that is no dataclass, is refused too.
    with h5py.File(path, "r+") as f:
        text = bytes(f["structure"][()]).decode().replace(f"{__name__}:Leaf", f"{__name__}:same")
        del f["structure"]
        f.create_dataset("structure", data=np.frombuffer(text.encode(), dtype=np.uint8))
    with pytest.raises(IiwaIdentError, match="not a dataclass"):
        read_tree(path, HERE)
    # A class another version named elsewhere (a module or a class this one does not have) is refused, not raised.
    for gone in (f"{__name__}.gone:Leaf", f"{__name__}:Gone"):
        with h5py.File(path, "r+") as f:
            text = bytes(f["structure"][()]).decode().replace(f"{__name__}:same", gone)
            del f["structure"]
            f.create_dataset("structure", data=np.frombuffer(text.encode(), dtype=np.uint8))
        with pytest.raises(IiwaIdentError, match="no such class in this version"):
            read_tree(path, HERE)
        with h5py.File(path, "r+") as f:
            text = bytes(f["structure"][()]).decode().replace(gone, f"{__name__}:same")
            del f["structure"]
            f.create_dataset("structure", data=np.frombuffer(text.encode(), dtype=np.uint8))


def test_what_cannot_be_stored_leaves_the_file_as_it_was(tmp_path):
    path = tmp_path / "t.h5"
    write_tree(path, {"x": 1.5})
    with pytest.raises(TypeError, match="a function cannot be stored"):
        write_tree(path, {"x": 2.5, "f": same})
    with pytest.raises(TypeError, match="object cannot be stored"):
        write_tree(path, {"a": np.array(["a", "b"], dtype=object)})
    assert read_tree(path, HERE) == {"x": 1.5}
    assert [p.name for p in tmp_path.iterdir()] == ["t.h5"]


def test_a_file_that_is_no_tree_is_named(tmp_path):
    other = tmp_path / "data.h5"
    with h5py.File(other, "w") as f:
        f["x"] = np.zeros(3)
    with pytest.raises(IiwaIdentError, match=rf"{other}: not a result tree"):
        read_tree(other, HERE)
    with pytest.raises(IiwaIdentError, match=rf"{tmp_path / 'none.h5'}: "):
        read_tree(tmp_path / "none.h5", HERE)
