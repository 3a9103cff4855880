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
