"""A long route's calibration: presented in chunks and kept sparse, the same S^R and the same readout."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy import sparse

import vprsnn_export.runtime.evaluation as evaluation
import vprsnn_export.trainer.calibrate as calibration
from vprsnn_export.io.checkpoint import load_checkpoint, save_checkpoint
from vprsnn_export.network.dynamics import FloatNetwork
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.runtime.evaluation import evaluate_float
from vprsnn_export.runtime.predictions import predictions
from vprsnn_export.trainer.calibrate import calibrate


def _sparse(ckpt):
    return type(ckpt)(**{**ckpt.__dict__, "calibration": sparse.csr_array(ckpt.calibration)})


def test_chunked_sparse_calibration_equals_the_whole(ensemble, monkeypatch):
    ckpt, data = ensemble
    cfg = ckpt.config
    network = FloatNetwork.from_arrays(ckpt.weights, ckpt.thresholds, cfg, torch.device("cpu"))
    references = {name: data.traversal(name) for name in ("summer", "winter")}
    whole = calibrate(network.counts, references, data.place_ids, cfg)
    assert isinstance(whole, np.ndarray) and whole.dtype == np.int64
    assert np.array_equal(
        calibrate(network.counts, {"summer": references["summer"]}, data.place_ids, cfg), ckpt.calibration
    )
    monkeypatch.setattr(calibration, "SPIKES_PER_CHUNK", 5 * cfg.encoder.timesteps * cfg.network.n_inputs)
    assert calibration.calibration_chunk(cfg, len(data.place_ids)) == 5
    chunked = calibrate(network.counts, references, data.place_ids, cfg, dense_entries=0)
    assert isinstance(chunked, sparse.csr_array) and chunked.dtype == np.int64
    assert chunked.has_canonical_format and np.all(chunked.data > 0)
    assert np.array_equal(chunked.toarray(), whole) and whole.sum() > ckpt.calibration.sum()
    isolated_off = cfg.replace(**{"network.state_isolation": False})
    assert calibration.calibration_chunk(isolated_off, len(data.place_ids)) == len(data.place_ids)


def test_a_sparse_checkpoint_round_trips_and_reads_out_as_the_dense_one(ensemble, tmp_path):
    ckpt, data = ensemble
    dense_path = save_checkpoint(tmp_path / "dense.npz", ckpt)
    sparse_path = save_checkpoint(tmp_path / "sparse.npz", _sparse(ckpt))
    with np.load(sparse_path) as npz:
        assert "calibration" not in npz.files and "calibration_indptr" in npz.files
    loaded = load_checkpoint(sparse_path)
    assert isinstance(loaded.calibration, sparse.csr_array)
    assert np.array_equal(loaded.calibration.toarray(), ckpt.calibration)
    assert isinstance(load_checkpoint(dense_path).calibration, np.ndarray)
    options = SequenceOptions(ks=(1, 3), tolerance=1)
    query = data.traversal("winter"), data.place_ids, "winter", options
    a, b = evaluate_float(ckpt, *query), evaluate_float(loaded, *query)
    assert a.rows == b.rows and a.modules == b.modules and a.silenced == b.silenced
    assert predictions(a.scored).to_csv() == predictions(b.scored).to_csv()


def test_a_long_routes_query_counts_are_sparse_blocks_and_read_out_the_same(ensemble, monkeypatch):
    ckpt, data = ensemble
    options = SequenceOptions(ks=(1, 3), tolerance=1)
    query = data.traversal("winter"), data.place_ids, "winter", options
    dense = evaluate_float(ckpt, *query)
    assert isinstance(dense.query_counts, np.ndarray)
    monkeypatch.setattr(evaluation, "DENSE_COUNT_ENTRIES", 0)
    monkeypatch.setattr(evaluation, "LONG_ROUTE_BLOCK", 5)
    long = evaluate_float(_sparse(ckpt), *query, progress=True)
    assert isinstance(long.query_counts, sparse.csr_array) and long.query_counts.dtype == np.int64
    assert np.array_equal(long.query_counts.toarray(), dense.query_counts)
    assert long.to_dict() == dense.to_dict()
    assert predictions(long.scored).to_csv() == predictions(dense.scored).to_csv()
    isolated_off = ckpt.config.replace(**{"network.state_isolation": False})
    assert not evaluation.sparse_query_counts(type(ckpt)(**{**ckpt.__dict__, "config": isolated_off}), 24)


def test_a_long_routes_joined_run_keeps_no_query_by_neuron_array(ensemble, monkeypatch):
    """Run in blocks, a long route keeps per query its candidates per step only: no final voltages (a
    (queries, neurons) array, 2.9 GB of float32 at 27k places), W+Prob rows or spike trains."""
    ckpt, data = ensemble
    monkeypatch.setattr(evaluation, "DENSE_COUNT_ENTRIES", 0)
    monkeypatch.setattr(evaluation, "LONG_ROUTE_BLOCK", 5)
    run, counts, _, spikes = evaluation._run_queries(
        _sparse(ckpt), data.traversal("winter"), data.place_ids, "winter", "auto", device=None, progress=False
    )
    assert spikes is None and run.final_voltage is None and run.raster is None and run.wprob is None
    assert run.candidates_per_step is not None and run.candidates_per_step.shape[0] == len(data.place_ids)
    assert isinstance(counts, sparse.csr_array) and counts.shape[0] == len(data.place_ids)


def test_an_evaluation_over_the_memory_limit_reads_out_in_the_largest_block_that_fits(ensemble, monkeypatch):
    """The readout block halves until the run's memory need fits: the same rows and predictions as the default
    block's; when even the smallest does not fit, its need is the one refused."""
    ckpt, data = ensemble
    options = SequenceOptions(ks=(1, 3), tolerance=1)
    query = data.traversal("winter"), data.place_ids, "winter", options
    whole = evaluate_float(ckpt, *query)
    real_check, blocks, asked = evaluation.check_run_memory, [], []

    def limited(cfg, what, *, readout_rows, **sizes):  # a limit between the needs of readout blocks 8 and 16
        asked.append(readout_rows)
        if readout_rows > 8 + max(options.ks):
            raise evaluation.InvalidValueError(f"{what} needs more than the limit ({readout_rows} rows)")
        return real_check(cfg, what, readout_rows=readout_rows, **sizes)

    real_blocks = evaluation.Readout.score_in_blocks

    def spied(self, *args, block, **kwargs):
        blocks.append(block)
        return real_blocks(self, *args, block=block, **kwargs)

    monkeypatch.setattr(evaluation, "check_run_memory", limited)
    monkeypatch.setattr(evaluation.Readout, "score_in_blocks", spied)
    monkeypatch.setattr(evaluation, "READOUT_BLOCKS", (32, 16, 8, 4))
    fitted = evaluate_float(ckpt, *query)
    assert asked == [35, 19, 11] and blocks == [8]  # 24 queries: read out in blocks of 8
    assert fitted.rows == whole.rows and predictions(fitted.scored).to_csv() == predictions(whole.scored).to_csv()
    monkeypatch.setattr(evaluation, "READOUT_BLOCKS", (32, 16))
    with pytest.raises(evaluation.InvalidValueError, match=r"\(19 rows\)"):
        evaluate_float(ckpt, *query)
