"""An ensemble checkpoint is evaluated over the whole route, with per-module rows and the region regularisation."""

import dataclasses

import numpy as np
import pytest

from vprsnn_export.config import Config
from vprsnn_export.data.dataset import load_dataset
from vprsnn_export.readout.regions import hyperactive_neurons, module_layout
from vprsnn_export.readout.scoring import Readout
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.runtime.evaluation import evaluate_float
from vprsnn_export.trainer.pipeline import train_and_calibrate

TINY = {"encoder.timesteps": 40, "train.epochs": 2, "network.n_neurons": 16, "train.module_size": 8}


@pytest.fixture(scope="module")
def ensemble():
    cfg = Config().replace(**TINY)
    data = load_dataset("synthetic:24", ["summer", "winter"], cfg.preprocess)
    return train_and_calibrate(data, ["summer"], cfg, progress=False), data


def evaluate(ckpt, data, **changes):
    ckpt = dataclasses.replace(ckpt, config=ckpt.config.replace(**changes)) if changes else ckpt
    options = SequenceOptions(ks=(1, 3))
    return evaluate_float(ckpt, data.traversal("winter"), data.place_ids, "winter", options)


def test_whole_route_rows_and_per_module_accuracy(ensemble):
    ckpt, data = ensemble
    assert ckpt.calibration.shape == (3 * 16, 24)
    off = {"assignment.hyperactive_share": 1.0, "assignment.outside_weight": 1.0}
    result = evaluate(ckpt, data, **off)
    assert [r["n_queries"] for r in result.rows] == [24] * 4
    assert result.silenced == 0
    assert result.modules is not None and [m.n_queries for m in result.modules] == [8, 8, 8]
    wprob = next(r for r in result.rows if r["strategy"] == "wprob" and r["k"] == 1)
    assert np.mean([m.accuracy for m in result.modules]) == pytest.approx(wprob["accuracy"])
    options = SequenceOptions(ks=(1, 3))
    plain = Readout(ckpt.calibration, ckpt.config.assignment.gamma, options).rows(
        result.query_counts, ckpt.reference_place_ids, data.place_ids
    )
    assert result.rows == [
        r.to_dict() for r in plain
    ]  # lambda = rho = 1: exactly the unregularised whole-route readout
    payload = result.to_dict()
    assert len(payload["modules"]) == 3 and payload["silenced_neurons"] == 0


def test_the_default_readout_is_regularised(ensemble):
    ckpt, data = ensemble
    result = evaluate(ckpt, data)
    layout = module_layout(ckpt.config, 24)
    assert (layout.outside_weight, layout.hyperactive_share) == (0.0, 0.5)
    assert result.silenced == int(hyperactive_neurons(ckpt.calibration, layout).sum())
    options = SequenceOptions(ks=(1, 3))
    rows = Readout(ckpt.calibration, ckpt.config.assignment.gamma, options, layout).rows(
        result.query_counts, ckpt.reference_place_ids, data.place_ids
    )
    assert result.rows == [r.to_dict() for r in rows]


def test_the_config_limit_silences_neurons(ensemble):
    ckpt, data = ensemble
    result = evaluate(ckpt, data, **{"assignment.hyperactive_share": 0.0})
    assert result.silenced is not None and result.silenced > 0
    assert len(result.rows) == 4


def test_single_network_has_no_module_rows():
    cfg = Config().replace(**{**TINY, "train.module_size": 0})
    data = load_dataset("synthetic:12", ["summer", "winter"], cfg.preprocess)
    ckpt = train_and_calibrate(data, ["summer"], cfg, progress=False)
    result = evaluate(ckpt, data)
    assert result.modules is None and "modules" not in result.to_dict()
