"""Bit-exactness: the fast integer simulator against the step-by-step reference, and against float."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from vprsnn_export.config import preset
from vprsnn_export.data.dataset import load_dataset
from vprsnn_export.data.encoding import query_spikes
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.export.quantize import QuantiseOptions, quantize_checkpoint
from vprsnn_export.network.dynamics import FloatNetwork
from vprsnn_export.targets.intsim import IntegerNetwork, matmul_dtype, prepare, run_prepared, simulate, step_agreement
from vprsnn_export.targets.reference_stepper import reference_run, trunc_div
from vprsnn_export.trainer.calibrate import calibrate
from vprsnn_export.trainer.pipeline import train_and_calibrate

NORDLAND = Path(__file__).resolve().parents[2].parent / "shared/data/nordland_64x32_summer_winter"


pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


def make_model(
    q, m, threshold, dv, bits, *, wta=True, isolation=True, per_neuron=True, timesteps=20, modules=1
) -> FixedPointModel:
    """``modules`` > 1: an ensemble of that many modules side by side (one place per module)."""
    n_inputs, n_neurons = q.shape
    side = int(round(n_inputs**0.5))
    cfg = preset("paper").replace(
        **{
            "preprocess.image_size": side,
            "preprocess.patch_size": 1,
            "network.n_inputs": n_inputs,
            "network.n_neurons": n_neurons // modules,
            "train.module_size": 1 if modules > 1 else 0,
            "network.wta": wta,
            "network.state_isolation": isolation,
            "encoder.timesteps": timesteps,
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
        calibration=np.zeros((n_neurons, modules), dtype=np.int64),
        float_calibration=np.zeros((n_neurons, modules), dtype=np.int64),
        reference_place_ids=np.arange(modules, dtype=np.int64),
        reference_traversals=["summer"],
        quantisation={"per_neuron": per_neuron},
        source_sha256="0" * 64,
    )


@st.composite
def cases(draw, saturating: bool = False):
    """A random small model and spike trains; ``saturating`` pushes voltages past 2**23 - 1."""
    side = 8 if saturating else draw(st.sampled_from([2, 3, 4]))
    modules = draw(st.integers(1, 3))
    n_neurons = modules * draw(st.integers(1, 4))
    bits = draw(st.integers(7, 8) if saturating else st.integers(2, 8))
    per_neuron = draw(st.booleans())
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    top = 2**bits
    q = rng.integers(top // 2 if saturating else 0, top, (side * side, n_neurons))
    multiplier_range = draw(st.sampled_from([4, 2**16]))  # small multipliers make a_j m_j ties likely
    m = (
        rng.integers(1, multiplier_range, n_neurons)
        if per_neuron
        else np.repeat(rng.integers(1, 2**16, modules), n_neurons // modules)
    )
    if saturating:
        threshold, dv = rng.integers(2**17 - 2**10, 2**17, n_neurons), draw(st.integers(0, 8))
    else:
        threshold = rng.integers(1, draw(st.sampled_from([8, 300, 2**17])), n_neurons)
        dv = draw(st.integers(0, 4095))
    model = make_model(
        q,
        m,
        threshold,
        dv,
        bits,
        wta=draw(st.booleans()),
        isolation=draw(st.booleans()),
        per_neuron=per_neuron,
        modules=modules,
    )
    shape = (draw(st.integers(1, 3)), draw(st.integers(35, 50) if saturating else st.integers(1, 12)), side * side)
    spikes = (rng.random(shape) < draw(st.floats(0.6, 1.0) if saturating else st.floats(0.05, 0.95))).astype(np.uint8)
    return model, spikes


def assert_identical(model: FixedPointModel, spikes: np.ndarray) -> tuple:
    fast = simulate(model, torch.from_numpy(spikes), record=True)
    slow = reference_run(model, spikes)
    assert np.array_equal(fast.raster.numpy(), slow.raster)
    assert np.array_equal(fast.final_voltage.numpy(), slow.final_voltage)
    assert np.array_equal(fast.counts.numpy(), slow.counts)
    assert np.array_equal(fast.candidates_per_step.numpy(), slow.candidates_per_step)
    assert fast.saturations == slow.saturations
    loop = run_prepared(
        prepare(model, torch.device("cpu")),
        torch.from_numpy(spikes),
        isolation=model.config.network.state_isolation,
        record=True,
        compiled=False,
    )
    assert np.array_equal(loop.raster.numpy(), slow.raster)
    assert np.array_equal(loop.final_voltage.numpy(), slow.final_voltage)
    return fast, slow


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cases())
def test_fast_simulator_equals_reference_on_random_models(case):
    assert_identical(*case)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cases(saturating=True))
def test_saturation_events_are_counted_identically(case):
    fast, _ = assert_identical(*case)
    event(f"saturated: {fast.saturations > 0}")


def test_saturation_happens_and_is_counted():
    q = np.full((64, 2), 255)
    model = make_model(q, [1, 1], [2**17 - 1, 2**17 - 1], 0, 8)
    fast, slow = assert_identical(model, np.ones((2, 12, 64), dtype=np.uint8))
    # 64 * 255 << 6 = 1044480 per step: the voltage passes 2**23 - 1 at step 9 and is clipped
    assert fast.saturations == slow.saturations == 2 * 2
    assert fast.max_current == 64 * 255
    assert fast.raster[:, 8].any() and not fast.raster[:, :8].any()


def test_ties_go_to_the_lowest_index_and_the_wta_compares_a_times_m():
    same = make_model(np.ones((4, 3)), [5, 5, 5], [1, 1, 1], 0, 2)
    run = simulate(same, torch.ones((1, 3, 4), dtype=torch.uint8), record=True)
    assert run.raster[0, :, 0].all() and not run.raster[0, :, 1:].any()
    q = np.array([[3, 1]] * 4)  # a = (12, 4)
    weighted = make_model(q, [1, 4], [1, 1], 0, 2)  # a m = (12, 16): neuron 1 wins despite the smaller current
    assert simulate(weighted, torch.ones((1, 1, 4), dtype=torch.uint8), record=True).raster[0, 0].tolist() == [
        False,
        True,
    ]
    assert_identical(weighted, np.ones((1, 5, 4), dtype=np.uint8))


def test_decay_truncates_toward_zero():
    assert [trunc_div(x, 4096) for x in (8191, -8191, 4095, -4095)] == [1, -1, 0, 0]
    model = make_model(np.ones((4, 1)), [1], [2**17 - 1], 205, 2)
    spikes = np.zeros((1, 4, 4), dtype=np.uint8)
    spikes[0, 0, 0] = 1
    voltage = 64
    for _ in range(3):
        voltage = voltage * (4096 - 205) // 4096  # 64 -> 60 -> 56 -> 53
    assert simulate(model, torch.from_numpy(spikes)).final_voltage.item() == voltage == 53


def test_wide_inputs_fall_back_to_an_exact_float64_matmul():
    q = np.full((1089, 2), 255)  # 1089 * 255 * 64 >= 2**24: float32 would round
    model = make_model(q, [1, 2], [2**16, 2**16], 100, 8)
    assert matmul_dtype(model, torch.device("cpu")) == torch.float64
    spikes = (np.random.default_rng(0).random((2, 6, 1089)) < 0.9).astype(np.uint8)
    assert_identical(model, spikes)
    narrow = make_model(np.full((784, 2), 255), [1, 1], [1, 1], 0, 8)
    assert matmul_dtype(narrow, torch.device("cpu")) == torch.float32


def test_counts_is_a_calibration_runner_and_accumulates_saturations():
    model = make_model(np.full((64, 2), 255), [1, 1], [2**17 - 1, 2**17 - 1], 0, 8, timesteps=60)
    network = IntegerNetwork(model)
    images = np.ones((3, 64), dtype=np.float32)
    result = calibrate(network.counts, {"a": images, "b": images}, np.arange(3), model.config)
    assert result.shape == (2, 3) and network.saturations > 0


def test_spike_trains_are_checked():
    model = make_model(np.ones((4, 2)), [1, 1], [1, 1], 0, 2)
    with pytest.raises(ValueError, match="shape"):
        simulate(model, torch.zeros((1, 3, 5), dtype=torch.uint8))
    with pytest.raises(ValueError, match="uint8"):
        simulate(model, torch.zeros((1, 3, 4), dtype=torch.float32))
    with pytest.raises(ValueError, match="0 or 1"):
        simulate(model, torch.full((1, 3, 4), 2, dtype=torch.uint8))


def test_step_agreement():
    a = torch.zeros((1, 4, 3), dtype=torch.bool)
    b = a.clone()
    a[0, 0, 1] = b[0, 0, 1] = True
    a[0, 1, 2] = True
    b[0, 1, 0] = True
    agreement = step_agreement(a, b)
    assert agreement["all_steps"] == 0.75 and agreement["active_steps"] == 0.5


def test_eight_bit_per_neuron_model_reproduces_the_float_winners():
    cfg = preset("paper").replace(
        **{"network.n_neurons": 32, "encoder.timesteps": 60, "train.epochs": 3, "train.batch_size": 8}
    )
    data = load_dataset("synthetic:16", ["summer", "winter"], cfg.preprocess)
    ckpt = train_and_calibrate(data, ["summer"], cfg, device=torch.device("cpu"), progress=False)
    model = quantize_checkpoint(ckpt, "0" * 64, 8, QuantiseOptions())
    spikes = query_spikes(data.traversal("winter"), data.place_ids, "winter", cfg)
    float_run = FloatNetwork.from_arrays(ckpt.weights, ckpt.thresholds, cfg, torch.device("cpu")).run(
        spikes, record=True
    )
    integer_run = simulate(model, spikes, record=True)
    agreement = step_agreement(float_run.raster, integer_run.raster)
    assert agreement["n_active_steps"] > 0.5 * agreement["n_steps"]
    assert agreement["all_steps"] >= 0.95, agreement


@pytest.mark.slow
def test_fast_equals_reference_on_the_real_nordland_subset():
    if not (NORDLAND / "subset_100_places.csv").is_file():
        pytest.skip(f"the Nordland subset is not at {NORDLAND}")
    cfg = preset("paper").replace(**{"train.epochs": 3})
    data = load_dataset(
        NORDLAND / "places.csv", ["summer", "winter"], cfg.preprocess, subset=NORDLAND / "subset_100_places.csv"
    )
    ckpt = train_and_calibrate(data, ["summer"], cfg, device=torch.device("cpu"), progress=False)
    spikes = query_spikes(data.traversal("winter")[:3], data.place_ids[:3], "winter", cfg)
    for bits in (8, 4, 2):
        for per_neuron in (False, True):
            model = quantize_checkpoint(ckpt, "0" * 64, bits, QuantiseOptions(per_neuron=per_neuron))
            fast, slow = assert_identical(model, spikes.numpy())
            assert fast.counts.sum() > 0
