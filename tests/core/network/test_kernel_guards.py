"""Every compiled kernel refuses, through its checked entry point, any array it would index out of bounds.

numba checks no bounds, so a short array would be read (or written) past its end. Each checked
entry point (beside each kernel: ``KERNEL_MODULES``) is called with valid arrays (it runs) and then with
each array in turn made short, empty, of the wrong dtype, non-contiguous, not an array or
read-only (when written): every variant raises InvalidValueError naming the argument.
"""

from __future__ import annotations

import ast
import inspect
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
import torch

from vprsnn_export.config import preset
from vprsnn_export.data import encoding_kernel, philox
from vprsnn_export.errors import InvalidValueError, VprError
from vprsnn_export.network import dynamics_kernel, kernel_sums
from vprsnn_export.network.dynamics import FloatNetwork, run_network
from vprsnn_export.targets import intsim_kernel
from vprsnn_export.targets.intsim import IntegerNetwork
from vprsnn_export.trainer import stdp_kernel

N, T, D, NEURONS, GROUP = 2, 5, 6, 4, 2
F32 = np.float32


def _spikes(shape: tuple[int, ...]) -> np.ndarray:
    return (np.random.default_rng(0).random(shape) < 0.5).astype(np.uint8)


def integer_args() -> dict[str, Any]:
    return dict(
        spikes=_spikes((N, T, D)),
        mantissas=np.arange(D * NEURONS, dtype=np.uint8).reshape(D, NEURONS) % 7,
        shift=6,
        threshold=np.full(NEURONS, 5 << 6, dtype=np.int64),
        multipliers=np.arange(1, NEURONS + 1, dtype=np.int64),
        use_multipliers=True,
        keep=4000,
        limit=(1 << 23) - 1,
        wta=True,
        group=GROUP,
        isolation=True,
        record=True,
        current_store=np.zeros(2 * T * NEURONS, dtype=np.int32),
        start=0,
        stop=NEURONS,
        tile=NEURONS,
        column=NEURONS // 2,
        chunk=2,
        counts=np.zeros((N, NEURONS), dtype=np.int64),
        n_candidates=np.zeros((N, T), dtype=np.int32),
        raster=np.zeros((N, T, NEURONS), dtype=np.bool_),
        final=np.zeros((N, NEURONS), dtype=np.int64),
    )


def float_args() -> dict[str, Any]:
    return dict(
        spikes=_spikes((N, T, D)),
        weights=np.linspace(0, 1, D * NEURONS, dtype=F32).reshape(D, NEURONS),
        theta=np.full(NEURONS, 0.8, dtype=F32),
        beta=F32(0.9),
        wta=True,
        group=GROUP,
        isolation=True,
        record=True,
        start=0,
        stop=NEURONS,
        tile=NEURONS,
        column=NEURONS // 2,
        chunk=2,
        counts=np.zeros((N, NEURONS), dtype=np.int64),
        n_candidates=np.zeros((N, T), dtype=np.int32),
        raster=np.zeros((N, T, NEURONS), dtype=np.bool_),
        final=np.zeros((N, NEURONS), dtype=F32),
    )


def stdp_args() -> dict[str, Any]:
    return dict(
        spikes=_spikes((N, T, D)),
        weights=np.full((D, NEURONS), 0.3, dtype=F32),
        theta=np.full(NEURONS, 0.5, dtype=F32),
        scalars=(F32(0.9), True, F32(0.8), F32(0.8), F32(0.01), F32(0.01), F32(1.0), True),
    )


def bernoulli_args() -> dict[str, Any]:
    return dict(
        thresholds=np.full((N, D), 1 << 23, dtype=np.int32),
        seeds=np.arange(N, dtype=np.int64),
        timesteps=T,
        out=np.zeros((N, T, D), dtype=np.uint8),
    )


def stdp_windows_args() -> dict[str, Any]:
    scalars = (F32(0.9), True, F32(0.8), F32(0.8), F32(0.01), F32(0.01), F32(1.0), True, False)
    return dict(
        limits=np.full((2, 3, D), 1 << 23, dtype=np.int32),
        seeds=np.arange(6, dtype=np.int64).reshape(2, 3),
        sizes=np.array([3, 2], dtype=np.int64),
        timesteps=T,
        weights=np.full((2, D, NEURONS), 0.3, dtype=F32),
        theta=np.full((2, NEURONS), 0.5, dtype=F32),
        scalars=scalars,
    )


def call_stdp_windows(scalars: tuple, **arrays: Any) -> Any:
    """:func:`stdp_kernel.stdp_windows_kernel` with its arrays by name (its scalars are positional)."""
    order = ("limits", "seeds", "sizes", "timesteps", "weights", "theta")
    return stdp_kernel.stdp_windows_kernel(*(arrays[name] for name in order), scalars[:8], scalars[8])


#: kernel -> (checked entry point, valid arguments, arguments written, arguments that set the sizes)
CASES: dict[str, tuple[Callable[..., Any], Callable[[], dict[str, Any]], set[str], set[str]]] = {
    "integer": (
        intsim_kernel.integer_kernel,
        integer_args,
        {"current_store", "counts", "n_candidates", "raster", "final"},
        {"spikes", "mantissas"},
    ),
    "float": (
        dynamics_kernel.float_kernel,
        float_args,
        {"counts", "n_candidates", "raster", "final"},
        {"spikes", "weights"},
    ),
    "stdp": (stdp_kernel.stdp_window_kernel, stdp_args, {"weights"}, {"spikes", "weights"}),
    "bernoulli": (encoding_kernel.bernoulli_kernel, bernoulli_args, {"out"}, {"thresholds"}),
    "stdp_windows": (call_stdp_windows, stdp_windows_args, {"weights"}, {"limits", "weights"}),
}

#: (kernel, argument, variant) that is a smaller but consistent problem, not a bad array
CONSISTENT = {
    ("stdp", "spikes", "short_first"),  # a smaller batch
}


def variants(array: np.ndarray, written: bool) -> dict[str, object]:
    found: dict[str, object] = {
        "empty": np.zeros((0,) * array.ndim, dtype=array.dtype),
        "wrong_dtype": array.astype(np.float64),
        "non_contiguous": np.repeat(array, 2, axis=-1)[..., ::2],
        "not_an_array": array.tolist(),
        "extra_axis": array[None],
    }
    if array.shape[-1] > 0:
        found["short_last"] = np.ascontiguousarray(array[..., :-1])
    if array.shape[0] > 0:
        found["short_first"] = np.ascontiguousarray(array[:-1])
    if written:
        frozen = array.copy()
        frozen.flags.writeable = False
        found["read_only"] = frozen
    return found


def bad_calls() -> list[tuple[str, str, str]]:
    calls = []
    for kernel, (_, make, written, _) in CASES.items():
        for name, value in make().items():
            if isinstance(value, np.ndarray):
                calls += [
                    (kernel, name, variant)
                    for variant in variants(value, name in written)
                    if (kernel, name, variant) not in CONSISTENT
                ]
    return calls


@pytest.mark.parametrize("kernel", sorted(CASES))
def test_valid_arrays_run(kernel):
    entry, make, _, _ = CASES[kernel]
    entry(**make())


@pytest.mark.parametrize(("kernel", "name", "variant"), bad_calls())
def test_bad_array_is_refused_by_name(kernel, name, variant):
    entry, make, written, roots = CASES[kernel]
    args = make()
    args[name] = variants(args[name], name in written)[variant]
    with pytest.raises(InvalidValueError) as caught:
        entry(**args)
    if name not in roots:  # an array that sets the sizes makes another one the mismatched one
        assert f" {name} " in str(caught.value)


@pytest.mark.parametrize(
    ("kernel", "name", "value"),
    [
        ("integer", "group", 3),
        ("integer", "stop", NEURONS + GROUP),
        ("integer", "start", 1),
        ("integer", "tile", 1),
        ("float", "group", 0),
        ("integer", "shift", 63),
        ("bernoulli", "timesteps", -1),
        ("stdp_windows", "sizes", np.array([4, 2], dtype=np.int64)),
        ("integer", "current_store", np.zeros(T * NEURONS - 1, dtype=np.int32)),
        ("float", "group", 2.0),
    ],
)
def test_bad_sizes_are_refused(kernel, name, value):
    entry, make, _, _ = CASES[kernel]
    args = make()
    args[name] = value
    with pytest.raises(InvalidValueError, match=name):
        entry(**args)


#: every module that holds compiled kernels: the shared sums and each kernel beside its caller
KERNEL_MODULES = (kernel_sums, encoding_kernel, philox, dynamics_kernel, intsim_kernel, stdp_kernel)


def compiled_kernels() -> set[str]:
    return {
        node.name
        for module in KERNEL_MODULES
        for node in ast.parse(inspect.getsource(module)).body
        if isinstance(node, ast.FunctionDef) and any(getattr(d, "id", None) == "compiled" for d in node.decorator_list)
    }


def test_compiled_kernels_are_called_from_python_only_through_checked_entry_points():
    """A compiled function may call another; a plain Python function only calls the checked entry points."""
    compiled = compiled_kernels()
    checked = {"integer_kernel", "float_kernel", "stdp_window_kernel", "bernoulli_kernel"}
    checked.add("stdp_windows_kernel")
    for module in KERNEL_MODULES:
        for node in ast.parse(inspect.getsource(module)).body:
            if not isinstance(node, ast.FunctionDef) or node.name in compiled | checked:
                continue
            called = {n.func.id for n in ast.walk(node) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)}
            assert not called & compiled, f"{module.__name__}.{node.name} calls {called & compiled} unchecked"


def small_config():
    return preset("paper").replace(
        **{"preprocess.image_size": 2, "preprocess.patch_size": 1, "network.n_inputs": 4, "network.n_neurons": 3}
    )


@pytest.mark.parametrize("n_thresholds", [0, 1, 2])
def test_float_network_with_too_few_thresholds_is_refused(n_thresholds):
    cfg = small_config()
    with pytest.raises(InvalidValueError, match="thresholds"):
        FloatNetwork(torch.rand(4, 3), torch.ones(n_thresholds), cfg)
    spikes = torch.ones((1, 5, 4), dtype=torch.uint8)
    for compiled in (True, False):
        with pytest.raises(InvalidValueError, match="thresholds"):
            run_network(spikes, torch.rand(4, 3), torch.ones(n_thresholds), beta=0.9, compiled=compiled)
    with pytest.raises(InvalidValueError, match="theta"):
        dynamics_kernel.float_run(spikes, torch.rand(4, 3), torch.ones(n_thresholds), beta=0.9)


def test_valid_fixed_point_model_runs(tiny_model):
    run = IntegerNetwork(tiny_model).run(torch.ones((2, 5, 4), dtype=torch.uint8))
    assert run.counts.shape == (2, 3) and int(run.counts.sum()) > 0


@pytest.mark.parametrize("name", ["threshold", "scale_multiplier"])
@pytest.mark.parametrize("length", [0, 1, 2, 4])
def test_fixed_point_model_with_short_arrays_is_refused(name, length, tiny_model):
    model = tiny_model
    setattr(model, name, np.ones(length, dtype=np.int32))
    with pytest.raises(InvalidValueError, match=name):
        IntegerNetwork(model)


def test_integer_run_with_short_thresholds_or_multipliers_is_refused():
    spikes = np.ones((1, 3, 4), dtype=np.uint8)
    q = np.ones((4, 3), dtype=np.int64)
    common: dict[str, Any] = dict(shift=6, keep=4000, limit=(1 << 23) - 1, wta=True)
    with pytest.raises(InvalidValueError, match="threshold"):
        intsim_kernel.integer_run(spikes, q, np.ones(2), None, **common)
    with pytest.raises(InvalidValueError, match="multipliers"):
        intsim_kernel.integer_run(spikes, q, np.ones(3), np.ones(1), **common)
    with pytest.raises(InvalidValueError, match="mantissas"):
        intsim_kernel.integer_run(spikes, np.ones((3, 3)), np.ones(3), None, **common)


def test_training_kernels_refuse_mismatched_thresholds():
    cfg = small_config()
    weights = torch.rand(4, 3)
    spikes = torch.ones((2, 5, 4), dtype=torch.uint8)
    with pytest.raises(VprError, match="theta"):
        stdp_kernel.stdp_window(weights, torch.ones(2), spikes, cfg)
    limits = np.zeros((1, 2, 4), dtype=np.int32)
    seeds = np.zeros((1, 2), dtype=np.int64)
    with pytest.raises(VprError, match="theta"):
        stdp_kernel.stdp_windows(
            np.ones((1, 4, 3), dtype=F32), np.ones((1, 2), dtype=F32), limits, seeds, np.array([2]), cfg
        )
