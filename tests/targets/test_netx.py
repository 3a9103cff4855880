"""network.net in lava-dl's netx (lava-dl 0.6, Python 3.10 venv): per-neuron and shared thresholds, spike for spike.

netx builds its own Dense + LIF from the HDF5 file (weights re-scaled by its optimize_weight_bits,
vThMant per neuron or one value); the run is WTA off and must equal the integer simulator's
WTA-off raster exactly. Slow: ``pytest -m slow tests/targets/test_netx.py`` (the venv fixtures
are in conftest.py).
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch

from vprsnn_export.config import preset
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.targets.intsim import simulate
from vprsnn_export.targets.loihi_description import NETX_NAME
from vprsnn_export.targets.loihi_target import write_loihi

RUN_LAVA = Path(__file__).resolve().parent / "lava_conformance" / "run_lava.py"


def full_size_model(bits: int, *, uniform: bool, p: float = 0.12) -> FixedPointModel:
    """784 x 400, random mantissas; thresholds 1.5-4 times each neuron's expected current at input rate p."""
    rng = np.random.default_rng(bits + 10 * uniform)
    cfg = preset("paper").replace(**{"network.wta": False, "encoder.timesteps": 40})
    q = rng.integers(0, 2**bits, (784, 400)).astype(np.int32)
    expected = p * q.sum(axis=0)
    threshold = np.full(400, 2.5 * expected.mean()) if uniform else expected * rng.uniform(1.5, 4, 400)
    return FixedPointModel(
        bits=bits,
        weight_mantissa=q,
        scale_multiplier=rng.integers(1, 2**16, 400).astype(np.int32),
        scale_exponent=-20,
        threshold=np.clip(np.round(threshold), 1, 2**17 - 1).astype(np.int32),
        decay_dv=205,
        config=cfg,
        calibration=np.zeros((400, 3), dtype=np.int64),
        float_calibration=np.zeros((400, 3), dtype=np.int64),
        reference_place_ids=np.arange(3, dtype=np.int64),
        reference_traversals=["summer"],
        quantisation={"per_neuron": True, "threshold_folding": uniform},
        source_sha256="0" * 64,
    )


def run_netx(python: Path, folder: Path, spikes: torch.Tensor, tmp_path: Path) -> torch.Tensor:
    np.save(tmp_path / "spikes.npy", spikes.numpy())
    done = subprocess.run(
        [str(python), str(RUN_LAVA), "--netx", str(folder), str(tmp_path / "spikes.npy"), str(tmp_path / "out.npy")],
        capture_output=True,
        text=True,
        timeout=1800,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return torch.from_numpy(np.load(tmp_path / "out.npy").astype(bool))


@pytest.mark.slow
@pytest.mark.parametrize(("bits", "uniform"), [(8, False), (4, False), (2, False), (4, True)])
def test_netx_runs_network_net_spike_for_spike(tmp_path, netx_python, bits, uniform):
    model = full_size_model(bits, uniform=uniform)
    written = write_loihi(model, tmp_path / "desc")
    assert written["netx"].name == NETX_NAME
    generator = torch.Generator().manual_seed(bits)
    spikes = (torch.rand((3, 40, 784), generator=generator) < 0.12).to(torch.uint8)
    netx = run_netx(netx_python, tmp_path / "desc", spikes, tmp_path)
    expected = simulate(model, spikes, record=True).raster
    assert int(expected.sum()) > 0
    assert torch.equal(netx, expected), f"{int((netx != expected).sum())} of {netx.numel()} spikes differ"


NORDLAND = Path(__file__).resolve().parents[2].parent / "shared/data/nordland_64x32_summer_winter"


@pytest.mark.slow
@pytest.mark.skipif(not os.environ.get("VPRSNN_LAVA_MODEL"), reason="set VPRSNN_LAVA_MODEL to a fixed-point model")
@pytest.mark.skipif(not NORDLAND.is_dir(), reason="the Nordland data folder is absent")
def test_netx_on_real_nordland_queries(tmp_path, netx_python):
    """VPRSNN_LAVA_MODEL's network.net on its first VPRSNN_LAVA_QUERIES (4) winter queries, at the model's T."""
    from vprsnn_export.data.dataset import load_dataset
    from vprsnn_export.data.encoding import query_spikes
    from vprsnn_export.export.model import load_fixed_point

    model = load_fixed_point(os.environ["VPRSNN_LAVA_MODEL"])
    n = int(os.environ.get("VPRSNN_LAVA_QUERIES", "4"))
    subset = NORDLAND / "subset_100_places.csv"
    dataset = load_dataset(NORDLAND / "places.csv", ["summer", "winter"], model.config.preprocess, subset=subset)
    spikes = query_spikes(dataset.traversal("winter")[:n], dataset.place_ids[:n], "winter", model.config)
    write_loihi(model, tmp_path / "desc")
    netx = run_netx(netx_python, tmp_path / "desc", spikes, tmp_path)
    wta_off = dataclasses.replace(model, config=model.config.replace(**{"network.wta": False}))
    expected = simulate(wta_off, spikes, record=True).raster
    assert torch.equal(netx, expected), f"{int((netx != expected).sum())} of {netx.numel()} spikes differ"
