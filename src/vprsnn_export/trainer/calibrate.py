"""Calibration: the reference spike-count matrix S^R (neurons x places) with plasticity off."""

from __future__ import annotations

import sys
from collections.abc import Callable, Mapping

import numpy as np
import torch
from scipy import sparse
from tqdm import tqdm

from vprsnn_export.config import Config
from vprsnn_export.data.encoding import calibration_spikes
from vprsnn_export.resources import MemoryNeed

CountRunner = Callable[[torch.Tensor], torch.Tensor]
"""Any network implementation: spikes (N, T, inputs) uint8 -> output spike counts (N, neurons)."""

#: The input spikes encoded at once, in bytes (uint8 (N, T, inputs)): a state-isolated network is calibrated
#: this many bytes of places at a time.
SPIKES_PER_CHUNK = 256 * 2**20
#: A count array (S^R: neurons x places; a route's query counts: queries x neurons) with more entries than this
#: is kept sparse (CSR): 512 MiB as dense int64.
DENSE_COUNT_ENTRIES = 2**26


def calibrate(
    run_counts: CountRunner,
    reference_images: Mapping[str, np.ndarray],
    place_ids: np.ndarray,
    cfg: Config,
    *,
    progress: bool = False,
    dense_entries: int = DENSE_COUNT_ENTRIES,
) -> np.ndarray | sparse.csr_array:
    """S^R_il = sum over reference traversals r of the spikes of neuron i for place l in traversal r.

    ``run_counts`` is the network under calibration (float, integer simulator,
    ONNX...), so a quantised network is calibrated with its own responses. A state-isolated network
    (``network.state_isolation``) is shown :data:`SPIKES_PER_CHUNK` bytes of input spikes at a time: each
    presentation's spikes are a pure function of its own seed and its counts of its own spikes, so the sums are
    the same as all at once. The counts are kept sparse (a presentation reaches at most T neurons) and S^R is
    returned dense int64 when it has at most ``dense_entries`` entries, else as an int64 CSR array: the same
    integers either way. ``progress``: a bar on stderr over the presentations.
    """
    chunk = calibration_chunk(cfg, len(place_ids))
    total: sparse.csr_array | None = None
    total_places = len(place_ids) * len(reference_images)
    with tqdm(
        total=total_places, desc="calibration", unit="place", file=sys.stderr, leave=False, disable=not progress
    ) as bar:
        for traversal, images in reference_images.items():
            parts = []
            for start in range(0, len(place_ids), chunk):
                ids = place_ids[start : start + chunk]
                spikes = calibration_spikes(images[start : start + chunk], ids, traversal, cfg)
                parts.append(sparse.csr_array(run_counts(spikes).cpu().numpy().astype(np.int64)))
                bar.update(len(ids))
            counts = sparse.vstack(parts, format="csr").T.tocsr()
            total = counts if total is None else total + counts
    assert total is not None
    return calibration_matrix(total, dense_entries)


def calibration_matrix(
    total: sparse.csr_array, dense_entries: int = DENSE_COUNT_ENTRIES
) -> np.ndarray | sparse.csr_array:
    """S^R as a checkpoint keeps it: dense int64 when it has at most ``dense_entries`` entries (column-major, as the
    transposed counts always were, so a checkpoint's bytes and its sha256 do not change), else the CSR array."""
    if total.shape[0] * total.shape[1] <= dense_entries:
        return np.asfortranarray(total.toarray())
    return total


def calibration_chunk(cfg: Config, presentations: int) -> int:
    """The presentations of one traversal encoded and run at once: :data:`SPIKES_PER_CHUNK` bytes of spikes when
    the network is state-isolated, else all of them (its voltage runs on from one presentation to the next)."""
    if not cfg.network.state_isolation:
        return presentations
    return max(1, min(presentations, SPIKES_PER_CHUNK // max(1, cfg.encoder.timesteps * cfg.network.n_inputs)))


def calibration_need(cfg: Config, presentations: int, n_neurons: int, places: int) -> MemoryNeed:
    """Calibrating ``n_neurons`` on ``presentations``: one chunk's input spikes and counts (int64, dense and as
    CSR), the weights, and S^R dense or as CSR (int64 + int32 index per entry, at most T entries per presentation)."""
    chunk, timesteps = calibration_chunk(cfg, presentations), cfg.encoder.timesteps
    entries = n_neurons * places
    sr = 8 * entries if entries <= DENSE_COUNT_ENTRIES else 12 * presentations * min(timesteps, n_neurons) * 2
    return MemoryNeed(
        (
            (f"input spikes {chunk} x {timesteps} x {cfg.network.n_inputs}", chunk * timesteps * cfg.network.n_inputs),
            (f"counts {chunk} x {n_neurons}", 2 * 8 * chunk * n_neurons),
            (f"weights {cfg.network.n_inputs} x {n_neurons} (2 copies)", 4 * cfg.network.n_inputs * n_neurons * 2),
            (f"S^R {n_neurons} x {places}", sr),
        )
    )
