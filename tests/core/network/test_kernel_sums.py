"""What every compiled kernel shares: spike arrays checked, and in-memory compilation where no cache is writable."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vprsnn_export.network import kernel_sums
from vprsnn_export.network.dynamics_kernel import float_run
from vprsnn_export.network.kernel_sums import as_spike_array

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


def test_spike_arrays_are_checked_and_bool_is_accepted():
    assert as_spike_array(torch.ones((1, 2, 3), dtype=torch.bool)).dtype == np.uint8
    with pytest.raises(ValueError, match="uint8 or bool"):
        as_spike_array(np.ones((1, 2, 3), dtype=np.float32))
    with pytest.raises(ValueError, match="shape"):
        as_spike_array(np.ones((2, 3), dtype=np.uint8))
    with pytest.raises(ValueError, match="do not match"):
        float_run(np.ones((1, 1, 2), np.uint8), np.ones((3, 1)), np.ones(1), beta=0.9)


def test_read_only_install_compiles_in_memory_with_a_warning(monkeypatch):
    """numba refuses cache=True when no cache directory is writable: the kernels fall back to in-memory compilation."""
    calls = []

    def fake_njit(**options):
        calls.append(options)
        if options.get("cache"):
            raise RuntimeError("cannot cache function: no locator available")
        return lambda function: function

    monkeypatch.setattr(kernel_sums, "njit", fake_njit)
    monkeypatch.setattr(kernel_sums, "_uncached", [])
    with pytest.warns(UserWarning, match="compiling them in memory"):
        function = kernel_sums.compiled(abs)
    numpy_errors = {"nogil": True, "error_model": "numpy"}
    assert function is abs and calls == [{"cache": True, **numpy_errors}, numpy_errors]


@pytest.mark.parametrize("active", [0, 1, 7, 8, 9, 16, 51])
def test_row_sum_adds_the_active_rows_one_after_another_in_increasing_input_order(active):
    """_row_sum's passes of eight rows give each total bit for bit as ((0 + w_i1) + w_i2) + ... in float32,
    across the passes and the rows left over (int32 sums of uint8 rows, the integer simulator's, exactly)."""
    rng = np.random.default_rng(active)
    weights = (rng.standard_normal((60, 37)) * 10.0 ** rng.integers(-3, 3, (60, 37))).astype(np.float32)
    index = np.sort(rng.choice(60, active, replace=False)).astype(np.int32)
    expected = np.zeros(37, dtype=np.float32)
    for i in index:
        expected = expected + weights[i]
    total = np.full(37, np.nan, dtype=np.float32)
    kernel_sums._row_sum(weights, index, active, total)
    assert total.tobytes() == expected.tobytes()
    mantissas = rng.integers(0, 256, (60, 37)).astype(np.uint8)
    integer_total = np.full(37, -1, dtype=np.int32)
    kernel_sums._row_sum(mantissas, index, active, integer_total)
    assert np.array_equal(integer_total, mantissas[index].astype(np.int64).sum(axis=0))
