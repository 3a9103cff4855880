"""Hypothesis over corrupted model files: any header edit, array swap or byte flip is read cleanly or
refused with one ModelFileError naming the file, never another exception."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vprsnn_export.errors import ModelFileError
from vprsnn_export.export.model import load_fixed_point
from vprsnn_export.io.checkpoint import load_checkpoint
from vprsnn_export.io.fileio import read_container, write_container

JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**70), 2**70) | st.floats() | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=6), inner, max_size=3),
    max_leaves=6,
)
ARRAYS = st.sampled_from(
    [np.array(3), np.zeros(0), np.full(4, np.nan), np.array(["x"]), np.ones((2, 2, 2)), np.array([1e300]), -np.ones(16)]
)
PROPERTY = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


@pytest.fixture(scope="module")
def files(tiny_checkpoint, quantised_model):
    """The session's checkpoint and 4-bit model files (tests/conftest.py), read only: edits go to copies."""
    return {"checkpoint": (tiny_checkpoint, load_checkpoint), "fixed-point model": (quantised_model, load_fixed_point)}


def loads_or_refuses(load, path) -> None:
    try:
        load(path)
    except ModelFileError as exc:
        assert str(path) in str(exc) and "\n" not in str(exc)


@pytest.mark.parametrize("kind", ["checkpoint", "fixed-point model"])
@PROPERTY
@given(data=st.data())
def test_any_header_edit_loads_or_is_refused(files, tmp_path, kind, data):
    source, load = files[kind]
    meta, arrays = read_container(source, kind)
    key = data.draw(st.sampled_from(sorted(meta)))
    if isinstance(meta[key], dict) and meta[key] and data.draw(st.booleans()):
        inner = data.draw(st.sampled_from(sorted(meta[key])))
        meta[key] = {**meta[key], inner: data.draw(JSON_VALUES)}
    else:
        meta[key] = data.draw(JSON_VALUES)
    loads_or_refuses(load, write_container(tmp_path / "edited.npz", json.loads(json.dumps(meta)), arrays))


@pytest.mark.parametrize("kind", ["checkpoint", "fixed-point model"])
@PROPERTY
@given(data=st.data())
def test_any_array_swap_loads_or_is_refused(files, tmp_path, kind, data):
    source, load = files[kind]
    meta, arrays = read_container(source, kind)
    arrays[data.draw(st.sampled_from(sorted(arrays)))] = data.draw(ARRAYS)
    loads_or_refuses(load, write_container(tmp_path / "swapped.npz", meta, arrays))


@pytest.mark.parametrize("kind", ["checkpoint", "fixed-point model"])
@PROPERTY
@given(position=st.floats(0, 1, exclude_max=True), byte=st.integers(0, 255), cut=st.booleans())
def test_any_flipped_byte_or_cut_loads_or_is_refused(files, tmp_path, kind, position, byte, cut):
    source, load = files[kind]
    content = bytearray(source.read_bytes())
    index = int(position * len(content))
    if cut:
        content = content[:index]
    else:
        content[index] = byte
    path = tmp_path / "flipped.npz"
    path.write_bytes(bytes(content))
    loads_or_refuses(load, path)
