import json

import numpy as np
import pytest

from vprsnn_export.config import preset
from vprsnn_export.errors import ModelFileError
from vprsnn_export.io.checkpoint import Checkpoint, load_checkpoint, save_checkpoint
from vprsnn_export.io.fileio import write_container


def _ckpt(cfg=None):
    cfg = cfg or preset("paper").replace(**{"network.n_neurons": 8})
    rng = np.random.default_rng(0)
    return Checkpoint(
        config=cfg,
        weights=rng.random((784, 8)).astype(np.float32),
        thresholds=np.full(8, 1.5, np.float32),
        calibration=rng.integers(0, 5, (8, 3)),
        reference_place_ids=np.array([4, 5, 6]),
        reference_traversals=["summer"],
        data={"source": "synthetic", "manifest_sha256": "x"},
    )


def test_round_trip(tmp_path):
    path = save_checkpoint(tmp_path / "c.npz", _ckpt())
    back = load_checkpoint(path)
    assert back.config == _ckpt().config
    np.testing.assert_array_equal(back.weights, _ckpt().weights)
    np.testing.assert_array_equal(back.calibration, _ckpt().calibration)
    assert back.reference_traversals == ["summer"]
    assert not list(tmp_path.glob(".*.tmp"))  # no temp file left behind


def test_truncated_file_is_a_clear_error(tmp_path):
    path = save_checkpoint(tmp_path / "c.npz", _ckpt())
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(ModelFileError, match="c.npz.*truncated or corrupt"):
        load_checkpoint(path)


def test_missing_file(tmp_path):
    with pytest.raises(ModelFileError, match="nope.npz: no such checkpoint"):
        load_checkpoint(tmp_path / "nope.npz")


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda c: setattr(c, "weights", c.weights[:100]), "weights has shape"),
        (lambda c: c.weights.__setitem__((0, 0), np.nan), "NaN"),
        (lambda c: setattr(c, "thresholds", np.ones(8, np.int32)), "dtype"),
        (lambda c: setattr(c, "calibration", -c.calibration - 1), "non-negative"),
    ],
)
def test_invalid_contents_are_rejected_on_save_and_load(tmp_path, mutate, message):
    bad = _ckpt()
    mutate(bad)
    with pytest.raises(ModelFileError, match=message):
        save_checkpoint(tmp_path / "bad.npz", bad)
    good = _ckpt()
    meta = {
        "format": "vprsnn-checkpoint",
        "format_version": 1,
        "config": good.config.to_dict(),
        "reference_traversals": ["summer"],
        "data": {},
    }
    write_container(
        tmp_path / "bad.npz",
        meta,
        {
            "weights": bad.weights,
            "thresholds": bad.thresholds,
            "calibration": bad.calibration,
            "reference_place_ids": bad.reference_place_ids,
        },
    )
    with pytest.raises(ModelFileError, match=message):
        load_checkpoint(tmp_path / "bad.npz")


def test_not_a_checkpoint(tmp_path):
    write_container(tmp_path / "other.npz", {"format": "something-else"}, {"a": np.zeros(2)})
    with pytest.raises(ModelFileError, match="not a vprsnn checkpoint"):
        load_checkpoint(tmp_path / "other.npz")
    (tmp_path / "text.npz").write_text(json.dumps({"hello": 1}))
    with pytest.raises(ModelFileError, match="truncated or corrupt"):
        load_checkpoint(tmp_path / "text.npz")


def test_identical_runs_write_byte_identical_checkpoints(tmp_path):
    from vprsnn_export.cli import main
    from vprsnn_export.io.checkpoint import checkpoint_sha256

    paths = [tmp_path / "a.npz", tmp_path / "b.npz"]
    for path in paths:
        argv = ["train", "--data", "synthetic:8", "--reference", "summer", "--out", str(path), "--quiet"]
        assert main([*argv, "--timesteps", "20", "--epochs", "2", "--neurons", "16"]) == 0
    assert checkpoint_sha256(paths[0]) == checkpoint_sha256(paths[1])
