"""The compiled integer kernel against the integer simulator and its reference stepper, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vprsnn_export.config import preset
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.network import parallel
from vprsnn_export.network.runs import SpikeRun
from vprsnn_export.targets.intsim import prepare, run_prepared
from vprsnn_export.targets.intsim_kernel import integer_run
from vprsnn_export.targets.reference_stepper import reference_run

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


@pytest.mark.parametrize("isolation", [True, False])
@pytest.mark.parametrize(("group", "threads"), [(None, 2), (4, 2), (4, 3)])
def test_integer_kernel_tiles_and_threads_change_no_number(isolation, group, threads, monkeypatch):
    """The integer kernel in tiles and on threads, a wide group in column blocks for chunks of presentations: the
    same run as one thread, one tile (saturations and peak too)."""
    gen = np.random.default_rng(5)
    q = gen.integers(0, 16, size=(30, 12))
    spikes = (gen.random((5, 40, 30)) < 0.2).astype(np.uint8)
    args = dict(shift=2, keep=4096 - 300, limit=900, wta=True, isolation=isolation, record=True, group=group)
    threshold = gen.integers(50, 200, size=12) << 2
    one = integer_run(spikes, q, threshold, None, threads=1, **args)
    monkeypatch.setattr(parallel, "TILE_NEURONS", 4)
    monkeypatch.setattr(parallel, "CURRENT_BYTES", 2 * 4 * 40 * 12)  # two presentations' currents
    many = integer_run(spikes, q, threshold, None, threads=threads, **args)
    for field in ("counts", "candidates_per_step", "raster", "final_voltage"):
        assert torch.equal(getattr(one, field), getattr(many, field)), field
    assert (one.saturations, one.max_current) == (many.saturations, many.max_current) and one.saturations > 0


@pytest.mark.parametrize("group", [None, 4])
def test_integer_kernel_lone_presentations_read_in_place_are_their_rows_of_the_batch(group, monkeypatch):
    """A lone presentation's integer currents read the mantissas in place, a batch's from copied tiles: the same."""
    monkeypatch.setattr(parallel, "TILE_NEURONS", 4)
    gen = np.random.default_rng(6)
    q = gen.integers(0, 16, size=(30, 12))
    spikes = (gen.random((4, 40, 30)) < 0.2).astype(np.uint8)
    args = dict(shift=2, keep=4096 - 300, limit=900, wta=True, isolation=True, record=True, group=group)
    threshold = gen.integers(50, 200, size=12) << 2
    batch = integer_run(spikes, q, threshold, None, **args)
    for p in range(len(spikes)):
        alone = integer_run(spikes[p : p + 1], q, threshold, None, **args)
        for field in ("counts", "raster", "final_voltage"):
            assert torch.equal(getattr(alone, field)[0], getattr(batch, field)[p]), field
