"""The compiled event-driven kernels against the integer simulator, its reference stepper and the float path."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vprsnn_export import kernels
from vprsnn_export.config import Config, preset
from vprsnn_export.dynamics import run_network
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.kernels import _blocked_currents, as_spike_array, blas_block, float_run, integer_run, stdp_window
from vprsnn_export.runs import SpikeRun
from vprsnn_export.targets.intsim import prepare, run_prepared
from vprsnn_export.targets.reference_stepper import reference_run
from vprsnn_export.trainer import train as train_module
from vprsnn_export.trainer.homeostasis import homeostasis_update
from vprsnn_export.trainer.stdp import initial_weights
from vprsnn_export.trainer.train import Presentation, train_batch, train_network

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


def make_model(q, m, threshold, dv, bits, *, wta=True, per_neuron=True) -> FixedPointModel:
    n_inputs, n_neurons = q.shape
    side = int(round(n_inputs**0.5))
    cfg = preset("paper").replace(
        **{
            "preprocess.image_size": side,
            "preprocess.patch_size": 1,
            "network.n_inputs": n_inputs,
            "network.n_neurons": n_neurons,
            "network.wta": wta,
        }
    )
    return FixedPointModel(
        bits=bits,
        weight_mantissa=np.asarray(q, dtype=np.int32),
        scale_multiplier=np.asarray(m, dtype=np.int32),
        scale_exponent=-20,
        threshold=np.asarray(threshold, dtype=np.int32),
        decay_dv=int(dv),
        config=cfg,
        calibration=np.zeros((n_neurons, 1), dtype=np.int64),
        float_calibration=np.zeros((n_neurons, 1), dtype=np.int64),
        reference_place_ids=np.zeros(1, dtype=np.int64),
        reference_traversals=["summer"],
        quantisation={"per_neuron": per_neuron},
        source_sha256="0" * 64,
    )


def kernel_run(model: FixedPointModel, spikes: np.ndarray, isolation: bool) -> SpikeRun:
    prep = prepare(model, torch.device("cpu"))
    return integer_run(
        spikes,
        model.weight_mantissa,
        prep.threshold.numpy(),
        None if prep.multipliers is None else prep.multipliers.numpy(),
        keep=prep.keep,
        limit=prep.limit,
        shift=prep.shift,
        wta=prep.wta,
        isolation=isolation,
        record=True,
    )


def assert_same_integer_run(model: FixedPointModel, spikes: np.ndarray, isolation: bool) -> SpikeRun:
    """Kernel == run_prepared (every field) == the reference stepper (what it reports)."""
    fast = kernel_run(model, spikes, isolation)
    sim = run_prepared(
        prepare(model, torch.device("cpu")), torch.from_numpy(spikes), isolation=isolation, record=True, compiled=False
    )
    for field in ("counts", "candidates_per_step", "raster", "final_voltage"):
        assert torch.equal(getattr(fast, field), getattr(sim, field)), field
    assert (fast.saturations, fast.max_current) == (sim.saturations, sim.max_current)
    slow = reference_run(model, spikes, state_isolation=isolation)
    assert torch.equal(fast.raster, slow.raster)
    assert torch.equal(fast.final_voltage, slow.final_voltage)
    assert torch.equal(fast.candidates_per_step, slow.candidates_per_step)
    assert fast.saturations == slow.saturations
    return fast


@st.composite
def integer_cases(draw):
    """Small random models: any bit width, equal or unequal multipliers (tie-prone or not), decays,
    thresholds from tiny (many candidates) to huge, WTA on/off, isolation on/off, and saturating ones."""
    saturating = draw(st.booleans())
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    n_inputs = draw(st.sampled_from([8, 10]) if saturating else st.integers(1, 4)) ** 2
    n_neurons = draw(st.integers(1, 7))
    bits = draw(st.integers(7, 8) if saturating else st.integers(2, 8))
    top = 2**bits
    q = rng.integers(top // 2 if saturating else 0, top, (n_inputs, n_neurons))
    per_neuron = draw(st.booleans())
    span = draw(st.sampled_from([3, 2**16]))
    m = rng.integers(1, span, n_neurons) if per_neuron else np.full(n_neurons, rng.integers(1, 2**16))
    if saturating:
        threshold, dv = rng.integers(2**17 - 2**10, 2**17, n_neurons), draw(st.integers(0, 8))
    else:
        threshold, dv = rng.integers(1, draw(st.sampled_from([8, 300, 2**17])), n_neurons), draw(st.integers(0, 4095))
    model = make_model(q, m, threshold, dv, bits, wta=draw(st.booleans()), per_neuron=per_neuron)
    steps = draw(st.integers(20, 40) if saturating else st.integers(1, 15))
    shape = (draw(st.integers(1, 3)), steps, n_inputs)
    density = draw(st.floats(0.6, 1.0) if saturating else st.floats(0.0, 1.0))
    spikes = (rng.random(shape) < density).astype(np.uint8)
    return model, spikes, draw(st.booleans())


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(integer_cases())
def test_integer_kernel_is_bit_identical_to_the_simulator_and_the_reference(case):
    assert_same_integer_run(*case)


def test_integer_kernel_counts_saturations_and_reports_the_unshifted_peak():
    model = make_model(np.full((64, 2), 255), [1, 1], [2**17 - 1, 2**17 - 1], 0, 8)
    run = assert_same_integer_run(model, np.ones((2, 12, 64), dtype=np.uint8), isolation=True)
    assert run.saturations == 4 and run.max_current == 64 * 255


def test_integer_kernel_ties_and_multipliers():
    same = make_model(np.ones((4, 3)), [5, 5, 5], [1, 1, 1], 0, 2)
    assert kernel_run(same, np.ones((1, 3, 4), dtype=np.uint8), True).raster[0, :, 0].all()
    weighted = make_model(np.array([[3, 1]] * 4), [1, 4], [1, 1], 0, 2)  # a m = (12, 16)
    assert kernel_run(weighted, np.ones((1, 1, 4), dtype=np.uint8), True).raster[0, 0].tolist() == [False, True]


def test_integer_kernel_wide_mantissas_use_int64_sums():
    q = np.full((36, 2), 2**26)  # sums beyond 2**31: the int64 path
    run = integer_run(
        np.ones((1, 3, 36), np.uint8), q, np.array([1, 1]), None, shift=6, keep=4096, limit=2**40, wta=True
    )
    assert run.max_current == 36 * 2**26 and run.counts.tolist() == [[3, 0]]
    with pytest.raises(ValueError, match="non-negative"):
        integer_run(
            np.ones((1, 1, 1), np.uint8), -np.ones((1, 1)), np.ones(1), None, shift=0, keep=1, limit=1, wta=True
        )


def float_case(seed: int, n: int = 4, timesteps: int = 40, n_inputs: int = 30, n_neurons: int = 9):
    gen = torch.Generator().manual_seed(seed)
    weights = torch.rand((n_inputs, n_neurons), generator=gen)
    theta = 0.5 + 2 * torch.rand(n_neurons, generator=gen)
    spikes = (torch.rand((n, timesteps, n_inputs), generator=gen) < 0.2).to(torch.uint8)
    return spikes, weights, theta


@pytest.mark.parametrize("wta", [True, False])
@pytest.mark.parametrize("isolation", [True, False])
@pytest.mark.parametrize("group", [None, 3])
def test_float_kernel_matches_run_network(wta, isolation, group):
    """``group`` 3: an ensemble of three modules of three neurons, one WTA winner per module."""
    for seed in range(4):
        spikes, weights, theta = float_case(seed)
        slow = run_network(
            spikes,
            weights,
            theta,
            beta=0.95,
            wta=wta,
            state_isolation=isolation,
            record=True,
            compiled=False,
            group=group,
        )
        fast = float_run(spikes, weights, theta, beta=0.95, wta=wta, isolation=isolation, record=True, group=group)
        if wta and group:
            assert int(fast.raster.view(*fast.raster.shape[:2], 3, 3).sum(dim=3).max()) <= 1
            assert int(fast.raster.sum(dim=2).max()) > 1  # several modules fire in one step
        assert torch.equal(fast.raster, slow.raster)
        assert torch.equal(fast.counts, slow.counts)
        assert torch.equal(fast.candidates_per_step, slow.candidates_per_step)
        if isolation:
            assert torch.equal(fast.final_voltage, slow.final_voltage)


def test_blocked_sums_reproduce_this_machines_blas_on_wide_inputs():
    """784 inputs: BLAS blocks its sums (MKL: 192 inputs); the probed block gives torch's currents bit for bit."""
    spikes, weights, _ = float_case(7, n=1, timesteps=64, n_inputs=784, n_neurons=40)
    block = blas_block(64, 784, 40)
    if block is None:
        pytest.skip("this machine's BLAS order is not one of the probed blockings")
    expected = torch.matmul(spikes[0].float(), weights).numpy()
    assert np.array_equal(_blocked_currents(spikes[0].numpy(), weights.numpy(), block), expected)


def test_float_kernel_exact_on_dyadic_weights_ties_to_the_lowest_index():
    """Weights that are multiples of 1/8 sum exactly in any order: the kernel must equal run_network bit for bit."""
    gen = torch.Generator().manual_seed(3)
    weights = torch.randint(0, 8, (25, 6), generator=gen).float() / 8
    weights[:, 3] = weights[:, 1]  # identical currents: ties
    theta = torch.tensor([1.0, 0.5, 2.0, 0.5, 1.5, 3.0])
    spikes = (torch.rand((3, 30, 25), generator=gen) < 0.3).to(torch.uint8)
    fast = float_run(spikes, weights, theta, beta=0.5, record=True)
    slow = run_network(spikes, weights, theta, beta=0.5, record=True, compiled=False)
    assert torch.equal(fast.raster, slow.raster) and torch.equal(fast.final_voltage, slow.final_voltage)


def test_spike_arrays_are_checked_and_bool_is_accepted():
    assert as_spike_array(torch.ones((1, 2, 3), dtype=torch.bool)).dtype == np.uint8
    with pytest.raises(ValueError, match="uint8 or bool"):
        as_spike_array(np.ones((1, 2, 3), dtype=np.float32))
    with pytest.raises(ValueError, match="shape"):
        as_spike_array(np.ones((2, 3), dtype=np.uint8))
    with pytest.raises(ValueError, match="do not match"):
        float_run(np.ones((1, 1, 2), np.uint8), np.ones((3, 1)), np.ones(1), beta=0.9)


def tiny_training_config(wta: bool = True, weight_norm: bool = True) -> Config:
    return preset("paper").replace(
        **{
            "preprocess.image_size": 4,
            "preprocess.patch_size": 1,
            "network.n_inputs": 16,
            "network.n_neurons": 6,
            "network.theta_init": 0.8,
            "network.wta": wta,
            "stdp.weight_norm": weight_norm,
            "stdp.a_plus": 0.05,
            "stdp.a_minus": 0.01,
            "encoder.timesteps": 25,
            "encoder.rate_scale": 0.6,
            "train.epochs": 3,
            "train.batch_size": 4,
        }
    )


@pytest.mark.parametrize("wta,weight_norm", [(True, True), (False, True), (True, False)])
def test_stdp_window_gives_train_batch_weights_bit_for_bit(wta, weight_norm):
    cfg = tiny_training_config(wta, weight_norm)
    gen = torch.Generator().manual_seed(5)
    weights = initial_weights(16, 6, gen)
    theta = torch.full((6,), 0.8)
    spikes = (torch.rand((4, 25, 16), generator=gen) < 0.4).to(torch.uint8)
    compiled = stdp_window(weights, theta, spikes, cfg)
    if compiled is None:
        pytest.skip("this machine's BLAS order is not reproducible")
    expected_weights, _, expected_fired = train_batch(weights, theta, spikes, cfg, compiled=False)
    assert torch.equal(compiled[0], expected_weights)
    assert torch.equal(compiled[1], expected_fired)


def test_training_through_the_kernel_gives_identical_weights(monkeypatch):
    """train_network with its batch loop routed through stdp_window: the same weights and thresholds for the seed."""
    cfg = tiny_training_config()
    rng = np.random.default_rng(0)
    images = rng.random((10, 16)).astype(np.float32)
    presentations = [Presentation("summer", p) for p in range(10)]

    def torch_batch(weights, theta, spikes, cfg):
        return train_batch(weights, theta, spikes, cfg, compiled=False)

    monkeypatch.setattr(train_module, "train_batch", torch_batch)
    expected = train_network(images, presentations, cfg, device=torch.device("cpu"), progress=False)

    def compiled_batch(weights, theta, spikes, cfg):
        result = stdp_window(weights, theta, spikes, cfg)
        if result is None:
            pytest.skip("this machine's BLAS order is not reproducible")
        weights, fired = result
        batch, timesteps, _ = spikes.shape
        return weights, homeostasis_update(theta, fired / (batch * timesteps), cfg.homeostasis), fired

    monkeypatch.setattr(train_module, "train_batch", compiled_batch)
    got = train_network(images, presentations, cfg, device=torch.device("cpu"), progress=False)
    assert torch.equal(got.weights, expected.weights)
    assert torch.equal(got.thresholds, expected.thresholds)


def test_read_only_install_compiles_in_memory_with_a_warning(monkeypatch):
    """numba refuses cache=True when no cache directory is writable: the kernels fall back to in-memory compilation."""
    calls = []

    def fake_njit(**options):
        calls.append(options)
        if options.get("cache"):
            raise RuntimeError("cannot cache function: no locator available")
        return lambda function: function

    monkeypatch.setattr(kernels, "njit", fake_njit)
    monkeypatch.setattr(kernels, "_uncached", [])
    with pytest.warns(UserWarning, match="compiling them in memory"):
        function = kernels.compiled(abs)
    numpy_errors = {"nogil": True, "error_model": "numpy"}
    assert function is abs and calls == [{"cache": True, **numpy_errors}, numpy_errors]


def test_an_ensemble_runs_each_module_as_it_would_run_alone():
    """Module m of an ensemble (grouped WTA) spikes exactly as the network of its neurons alone."""
    spikes, weights, theta = float_case(11, n_neurons=12)
    whole = float_run(spikes, weights, theta, beta=0.9, record=True, group=4)
    for module in range(3):
        cut = slice(4 * module, 4 * module + 4)
        alone = float_run(spikes, weights[:, cut].contiguous(), theta[cut].contiguous(), beta=0.9, record=True)
        assert torch.equal(whole.raster[:, :, cut], alone.raster)
    with pytest.raises(ValueError, match="do not divide"):
        float_run(spikes, weights, theta, beta=0.9, group=5)


@pytest.mark.parametrize("isolation", [True, False])
@pytest.mark.parametrize(("group", "threads"), [(None, 2), (4, 2), (4, 3), (1000, 2)])
def test_float_kernel_tiles_and_threads_change_no_number(isolation, group, threads, monkeypatch):
    """Tiles of whole WTA groups, threads over groups or presentations: the same run as one thread, one tile."""
    n_neurons = 1000 if group == 1000 else 12
    spikes, weights, theta = float_case(13, n=5, n_neurons=n_neurons)
    one = float_run(spikes, weights, theta, beta=0.9, isolation=isolation, record=True, group=group, threads=1)
    monkeypatch.setattr(kernels, "TILE_NEURONS", 4)
    many = float_run(spikes, weights, theta, beta=0.9, isolation=isolation, record=True, group=group, threads=threads)
    for field in ("counts", "candidates_per_step", "raster", "final_voltage"):
        assert torch.equal(getattr(one, field), getattr(many, field)), field


@pytest.mark.parametrize("isolation", [True, False])
@pytest.mark.parametrize(("group", "threads"), [(None, 2), (4, 2), (4, 3)])
def test_integer_kernel_tiles_and_threads_change_no_number(isolation, group, threads, monkeypatch):
    """The integer kernel in tiles and on threads: the same run as one thread, one tile (saturations and peak too)."""
    gen = np.random.default_rng(5)
    q = gen.integers(0, 16, size=(30, 12))
    spikes = (gen.random((5, 40, 30)) < 0.2).astype(np.uint8)
    args = dict(shift=2, keep=4096 - 300, limit=900, wta=True, isolation=isolation, record=True, group=group)
    threshold = gen.integers(50, 200, size=12) << 2
    one = integer_run(spikes, q, threshold, None, threads=1, **args)
    monkeypatch.setattr(kernels, "TILE_NEURONS", 4)
    many = integer_run(spikes, q, threshold, None, threads=threads, **args)
    for field in ("counts", "candidates_per_step", "raster", "final_voltage"):
        assert torch.equal(getattr(one, field), getattr(many, field)), field
    assert (one.saturations, one.max_current) == (many.saturations, many.max_current) and one.saturations > 0


@pytest.mark.parametrize("group", [None, 40, 37])
def test_wide_wta_groups_pick_the_first_largest_candidate_as_run_network(group):
    """Groups wider than the 16 lanes of the branch-free argmax (and a ragged tail), with ties: run_network's winners."""
    for seed in range(3):
        spikes, weights, theta = float_case(seed, n=3, timesteps=60, n_neurons=(80 if group != 37 else 74))
        weights = torch.floor(weights * 4) / 8  # dyadic: exact sums, many tied currents
        theta = theta * 0.3
        slow = run_network(spikes, weights, theta, beta=0.95, record=True, compiled=False, group=group)
        fast = float_run(spikes, weights, theta, beta=0.95, record=True, group=group)
        assert int(slow.candidates_per_step.max()) > 16
        assert torch.equal(fast.raster, slow.raster) and torch.equal(fast.counts, slow.counts)
