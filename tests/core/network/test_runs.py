"""run_in_chunks: progress bars over chunks of presentations change no spike, and close on errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tqdm import tqdm

from vprsnn_export.network.dynamics import FloatNetwork
from vprsnn_export.network.runs import SpikeRun, run_in_chunks
from vprsnn_export.targets.intsim import IntegerNetwork

pytestmark = pytest.mark.usefixtures("one_thread")


def _spikes(rng: np.random.Generator, n: int, timesteps: int = 20, n_inputs: int = 16) -> torch.Tensor:
    return torch.as_tensor((rng.random((n, timesteps, n_inputs)) < 0.3).astype(np.uint8))


def test_float_network_counts_equal_with_and_without_the_bar(small_config, capsys):
    rng = np.random.default_rng(3)
    cfg = small_config()
    weights = rng.random((16, 6)).astype(np.float32)
    thresholds = rng.uniform(0.5, 3.0, 6).astype(np.float32)
    spikes = _spikes(rng, 300)
    quiet = FloatNetwork.from_arrays(weights, thresholds, cfg, torch.device("cpu")).run(spikes, record=True)
    shown = FloatNetwork.from_arrays(weights, thresholds, cfg, torch.device("cpu"))
    shown.progress = True
    loud = shown.run(spikes, record=True)
    assert int(quiet.counts.sum()) > 0
    assert torch.equal(quiet.counts, loud.counts)
    assert quiet.raster is not None and loud.raster is not None and torch.equal(quiet.raster, loud.raster)
    assert quiet.candidates_per_step is not None and loud.candidates_per_step is not None
    assert torch.equal(quiet.candidates_per_step, loud.candidates_per_step)
    assert "float" in capsys.readouterr().err


def test_integer_network_counts_and_saturations_equal_with_and_without_the_bar(make_model, capsys):
    rng = np.random.default_rng(4)
    model = make_model(rng, bits=4)
    spikes = _spikes(rng, 300)
    quiet = IntegerNetwork(model).run(spikes)
    loud_network = IntegerNetwork(model, progress=True)
    loud = loud_network.run(spikes)
    assert int(quiet.counts.sum()) > 0
    assert torch.equal(quiet.counts, loud.counts)
    assert quiet.saturations == loud.saturations == loud_network.saturations
    assert quiet.max_current == loud.max_current
    assert "integer simulator" in capsys.readouterr().err
    assert capsys.readouterr().err == ""
    IntegerNetwork(model).run(spikes)
    assert capsys.readouterr().err == "", "the library default is silent"


def test_a_failing_chunk_closes_the_bar_and_leaves_no_line(capsys):
    calls = []

    def failing(part: torch.Tensor) -> SpikeRun:
        calls.append(len(part))
        if len(calls) == 2:
            raise ValueError("bad chunk")
        return SpikeRun(counts=torch.zeros((len(part), 2), dtype=torch.int64))

    with pytest.raises(ValueError, match="bad chunk"):
        run_in_chunks(failing, torch.zeros((10, 2, 2), dtype=torch.uint8), chunk=4, progress=True, desc="demo")
    err = capsys.readouterr().err
    assert calls == [4, 4]
    assert "demo" in err, "the bar was shown"
    assert err.split("\r")[-1].strip() == "", "the bar was cleared: nothing left on the last line"
    assert not tqdm._instances
