"""The readout in query blocks (issue 43): every column, row and prediction equals the whole-matrix readout's,
bit for bit, while no (queries x places) matrix is held."""

from __future__ import annotations

import numpy as np
import pytest

from vprsnn_export.config import Config
from vprsnn_export.data.truth import GroundTruth, MatchWindow
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.readout.scoring import Readout
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.runtime.predictions import predictions


def route_counts(places: int, neurons: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """S^R and query counts shaped like a trained route's: a neuron fires for a few neighbouring places."""
    rng = np.random.default_rng(seed)
    sr = np.zeros((neurons, places), dtype=np.int64)
    home = rng.integers(0, places, neurons)
    for offset in range(-3, 4):
        sr[np.arange(neurons), np.clip(home + offset, 0, places - 1)] += rng.poisson(4.0, neurons)
    favourite = np.argsort(home)[np.clip(np.arange(places) * neurons // places, 0, neurons - 1)]
    counts = rng.poisson(0.02, (places, neurons))
    counts[np.arange(places), favourite] += rng.poisson(6.0, places)
    return sr, counts


def same_columns(a, b) -> None:
    assert [(c.strategy, c.k) for c in a.columns] == [(c.strategy, c.k) for c in b.columns]
    for x, y in zip(a.columns, b.columns, strict=True):
        np.testing.assert_array_equal(x.index, y.index)
        assert x.confidence.tobytes() == y.confidence.tobytes()  # bit for bit
        np.testing.assert_array_equal(x.correct, y.correct)
        assert x.row == y.row
    assert predictions(a).to_csv() == predictions(b).to_csv()


@pytest.mark.parametrize(
    ("places", "block", "options"),
    [
        (601, 64, SequenceOptions(ks=(1, 5, 10))),
        (700, 128, SequenceOptions(ks=(1, 3), velocity=0.8, rule="sum")),
        (333, 1024, SequenceOptions(ks=(1, 70), velocity=-1.5)),  # a window longer than the block's history
    ],
)
def test_blocks_decide_what_the_whole_matrix_decides(places, block, options):
    """Also run under OMP_NUM_THREADS=2 (numpy's BLAS on two threads): equal there too."""
    sr, counts = route_counts(places, places)
    ids = np.arange(places) + 10
    readout = Readout(sr, 0.5, options)
    whole = readout.score(counts, ids, ids, MatchWindow(1))
    blocks = readout.score_in_blocks(counts, ids, ids, MatchWindow(1), block=block)
    same_columns(whole, blocks)
    assert blocks.scores == {} and blocks.aggregates == {} and blocks.ks == whole.ks


def test_an_ensemble_with_frame_positions_and_a_ground_truth_reads_out_alike():
    places, module = 640, 64
    sr, counts = route_counts(places, places, seed=3)
    cfg = Config().replace(**{"train.module_size": module, "network.n_neurons": 64})
    options = SequenceOptions(ks=(1, 4, 9), velocity=1.25)
    readout = Readout.of(sr, cfg, options)
    assert readout.modules is not None
    ids = np.arange(places)
    matrix = np.zeros((places, places), dtype=bool)
    matrix[ids, ids] = matrix[np.clip(ids + 1, 0, places - 1), ids] = True
    truth = GroundTruth(matrix, "gt.npy")
    positions = np.cumsum(np.random.default_rng(1).integers(1, 3, places))  # dropped frames
    whole = readout.score(counts, ids, ids, truth, positions)
    blocks = readout.score_in_blocks(counts, ids, ids, truth, positions, block=64)
    same_columns(whole, blocks)
    assert [m.to_dict() for m in whole.regions(readout.modules.regions, 4)] == [
        m.to_dict() for m in blocks.regions(readout.modules.regions, 4)
    ]


def test_a_velocity_searched_over_the_stream_is_read_out_whole():
    sr, counts = route_counts(100, 100)
    ids = np.arange(100)
    readout = Readout(sr, 0.5, SequenceOptions(ks=(1, 3), velocity_candidates=(0.5, 1.0)))
    with pytest.raises(InvalidValueError, match="read the queries out whole"):
        readout.score_in_blocks(counts, ids, ids)


def test_the_new_types_refuse_bad_values_when_built():
    """Guards at the edges (issue 42's types): one clear InvalidValueError naming what is wrong."""
    from vprsnn_export.data.truth import Query
    from vprsnn_export.runtime.verify import Runtime, VerifiedNetwork

    with pytest.raises(InvalidValueError, match="match window"):
        MatchWindow(-1)
    with pytest.raises(InvalidValueError, match="2-D boolean"):
        GroundTruth(np.ones((3, 2)), "gt.npy")
    with pytest.raises(InvalidValueError, match="one row per place id"):
        Query("winter", np.zeros((3, 4)), np.arange(2))
    with pytest.raises(InvalidValueError, match="truth must be a Truth"):
        Query("winter", np.zeros((2, 4)), np.arange(2), truth=1)  # type: ignore[arg-type]
    with pytest.raises(InvalidValueError, match="checkpoint must be a Checkpoint"):
        VerifiedNetwork("net.npz", "sha")  # type: ignore[arg-type]
    with pytest.raises(InvalidValueError, match="device must be a device"):
        Runtime(device="cpu")  # type: ignore[arg-type]
    sr, counts = route_counts(80, 80)
    ids = np.arange(80)
    with pytest.raises(InvalidValueError, match="block must be an integer"):
        Readout(sr, 0.5).score_in_blocks(counts, ids, ids, block="64")  # type: ignore[arg-type]


def test_the_block_readout_shows_its_progress_only_when_asked(capsys):
    """A long route's readout takes minutes (1.6 at 27k): with ``progress`` a bar of queries on stderr, the same
    columns; without, nothing printed."""
    sr, counts = route_counts(200, 200)
    readout, ids = Readout(sr, 0.5), np.arange(200)
    quiet = readout.score_in_blocks(counts, ids, ids, block=64)
    assert capsys.readouterr().err == ""
    shown = readout.score_in_blocks(counts, ids, ids, block=64, progress=True)
    assert "readout" in capsys.readouterr().err
    same_columns(quiet, shown)
