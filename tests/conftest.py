"""Shared test factories and trained networks: a small config, a random fixed-point model or float
checkpoint, networks trained once per session, one torch thread.

The tests import in importlib mode, so the factories are handed out as fixtures:
``def test_x(make_model): model = make_model(rng, bits=4)``. A module that wants one
intra-op thread for its tiny tensors says ``pytestmark = pytest.mark.usefixtures("one_thread")``.

Trained networks are session-scoped and built once per run (training is deterministic: a seed
fixes it), so a test that does not test training itself asks for one instead of training its own:
``trained`` (a float checkpoint and its synthetic data set), ``ensemble`` (one of modules),
``tiny_checkpoint`` and ``quantised_model`` (files written by the command line), or the factories
``train_network(data, **overrides)`` and ``cli_checkpoint(data, *options)`` for another size.
They are shared: a test copies a file or ``dataclasses.replace``s a checkpoint before changing it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import settings

from vprsnn_export.cli import main
from vprsnn_export.config import Config, preset
from vprsnn_export.data.dataset import Dataset, load_dataset
from vprsnn_export.data.synthetic import synthetic_route
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.io.checkpoint import Checkpoint
from vprsnn_export.trainer.pipeline import train_and_calibrate

#: Property tests are judged on their examples, never on time: the 2-core machine is shared, and a
#: per-example deadline fails a correct test under load. One profile for every test module.
settings.register_profile("vprsnn", deadline=None)
settings.load_profile("vprsnn")


@pytest.fixture(autouse=True)
def own_results_folder(monkeypatch):
    """``experiment``'s default output ($VPRSNN_RESULTS) per test: never the user's ~/.cache, and never a folder
    that two tests on two workers lock at once. A short path: --help prints it whole on one line."""
    import shutil
    import tempfile

    folder = tempfile.mkdtemp(prefix="vr")
    monkeypatch.setenv("VPRSNN_RESULTS", f"{folder}/results")
    yield
    shutil.rmtree(folder, ignore_errors=True)


@pytest.fixture
def one_thread():
    """Small tensors: one intra-op thread avoids oversubscribing the shared cores."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _small_config(n_inputs: int = 16, n_neurons: int = 6, **overrides) -> Config:
    """The paper's preset on sqrt(n_inputs) x sqrt(n_inputs) images, one pixel per patch, 20 time steps."""
    side = int(round(n_inputs**0.5))
    return preset("paper").replace(
        **{
            "preprocess.image_size": side,
            "preprocess.patch_size": 1,
            "network.n_inputs": n_inputs,
            "network.n_neurons": n_neurons,
            "encoder.timesteps": 20,
            **overrides,
        }
    )


def _make_model(
    rng: np.random.Generator,
    *,
    bits: int = 8,
    wta: bool = True,
    dv: int = 205,
    uniform: bool = False,
    n_inputs: int = 16,
    n_neurons: int = 6,
) -> FixedPointModel:
    """A random fixed-point model of n_neurons over n_inputs with three reference places (5, 7, 9)."""
    cfg = _small_config(n_inputs, n_neurons, **{"network.wta": wta})
    threshold = np.full(n_neurons, 300) if uniform else rng.integers(50, 600, n_neurons)
    return FixedPointModel(
        bits=bits,
        weight_mantissa=rng.integers(0, 2**bits, (n_inputs, n_neurons)).astype(np.int32),
        scale_multiplier=rng.integers(1, 2**16, n_neurons).astype(np.int32),
        scale_exponent=-20,
        threshold=threshold.astype(np.int32),
        decay_dv=dv,
        config=cfg,
        calibration=rng.integers(0, 4, (n_neurons, 3)).astype(np.int64),
        float_calibration=rng.integers(0, 4, (n_neurons, 3)).astype(np.int64),
        reference_place_ids=np.array([5, 7, 9], dtype=np.int64),
        reference_traversals=["summer"],
        quantisation={"per_neuron": True, "scale_method": "max"},
        source_sha256="ab" * 32,
        data={"source": "synthetic"},
    )


def _make_checkpoint(
    rng: np.random.Generator,
    *,
    beta: float = 0.95,
    wta: bool = True,
    dyadic: bool = False,
    uniform: bool = False,
    history: list | None = None,
) -> Checkpoint:
    """A random 16-input, 6-neuron float checkpoint of :func:`_small_config` with three reference places (1, 2, 3).

    ``uniform``: one threshold (2.25) for all neurons, weights in [0, 0.5); else thresholds in [1, 2).
    ``dyadic``: weights on a 1/16 grid, thresholds on a 1/4 grid, beta 0.5: every float32 sum is exact.
    """
    cfg = _small_config(**{"network.beta": 0.5 if dyadic else beta, "network.wta": wta})
    weights = rng.integers(0, 16, (16, 6)) / 16.0 if dyadic else rng.random((16, 6)) * 0.5
    thresholds = np.full(6, 2.25) if uniform else (rng.integers(4, 12, 6) / 4.0 if dyadic else rng.random(6) + 1.0)
    return Checkpoint(
        config=cfg,
        weights=weights.astype(np.float32),
        thresholds=thresholds.astype(np.float32),
        calibration=rng.integers(0, 4, (6, 3)).astype(np.int64),
        reference_place_ids=np.array([1, 2, 3], dtype=np.int64),
        reference_traversals=["summer"],
        data={"source": "synthetic", "subset": None},
        history=[] if history is None else history,
    )


@pytest.fixture
def make_checkpoint():
    """The factory ``make_checkpoint(rng, *, beta, wta, dyadic, uniform, history) -> Checkpoint`` (hand-set, untrained)."""
    return _make_checkpoint


#: The small network the session trains by default: 40 time steps, 2 epochs, 16 neurons on 24 synthetic places.
TRAINED = {"encoder.timesteps": 40, "train.epochs": 2, "network.n_neurons": 16}
#: `vprsnn-export train` options of the tiny network the command-line tests share (8 synthetic places).
TINY_TRAIN = ("--timesteps", "20", "--epochs", "1", "--neurons", "16", "--quiet")


@pytest.fixture(scope="session")
def train_network():
    """The factory ``train_network(data="synthetic:24", **overrides) -> (Checkpoint, Dataset)``: the float network of
    ``Config()`` with :data:`TRAINED` and ``overrides`` trained on the summer traversal of ``data`` (summer and
    winter), once per session for each argument set."""
    made: dict[str, tuple[Checkpoint, Dataset]] = {}

    def train(data: str = "synthetic:24", **overrides) -> tuple[Checkpoint, Dataset]:
        key = repr((data, sorted(overrides.items())))
        if key not in made:
            cfg = Config().replace(**{**TRAINED, **overrides})
            dataset = load_dataset(data, ["summer", "winter"], cfg.preprocess)
            selection = {"subset": None, "places": None}  # recorded as `train --data DATA` records it
            made[key] = train_and_calibrate(dataset, ["summer"], cfg, progress=False, selection=selection), dataset
        return made[key]

    return train


@pytest.fixture(scope="session")
def trained(train_network) -> tuple[Checkpoint, Dataset]:
    """A small trained float checkpoint (:data:`TRAINED`, 24 synthetic places) and its data set."""
    return train_network()


@pytest.fixture(scope="session")
def ensemble(train_network) -> tuple[Checkpoint, Dataset]:
    """The :func:`trained` network as an ensemble of three modules of 8 places, and its data set."""
    return train_network(**{"train.module_size": 8})


@pytest.fixture(scope="session")
def synthetic_data(trained) -> Dataset:
    """The synthetic data set (24 places, summer and winter) the :func:`trained` network was trained on."""
    return trained[1]


@pytest.fixture(scope="session")
def cli_checkpoint(tmp_path_factory):
    """The factory ``cli_checkpoint(data="synthetic:8", *options) -> Path``: the checkpoint that
    ``vprsnn-export train --data DATA --reference summer OPTIONS`` writes, once per session for each argument set."""
    made: dict[tuple[str, ...], Path] = {}

    def train(data: str = "synthetic:8", *options: str) -> Path:
        key = (data, *options)
        if key not in made:
            path = tmp_path_factory.mktemp("trained") / "net.npz"
            assert main(["train", "--data", data, "--reference", "summer", "--out", str(path), *options]) == 0
            made[key] = path
        return made[key]

    return train


@pytest.fixture(scope="session")
def tiny_checkpoint(cli_checkpoint) -> Path:
    """The checkpoint file of ``train --data synthetic:8 --reference summer`` with :data:`TINY_TRAIN` (read-only)."""
    return cli_checkpoint("synthetic:8", *TINY_TRAIN)


@pytest.fixture(scope="session")
def quantised_model(tiny_checkpoint, tmp_path_factory) -> Path:
    """The 4-bit fixed-point model file ``quantize`` writes of :func:`tiny_checkpoint` (read-only)."""
    folder = tmp_path_factory.mktemp("quantised") / "q"
    assert main(["quantize", str(tiny_checkpoint), "--bits", "4", "--out", str(folder), "--quiet"]) == 0
    return next(folder.glob("*.npz"))


@pytest.fixture
def tiny_model() -> FixedPointModel:
    """A 4-input, 3-neuron 4-bit fixed-point model with hand-set integers (thresholds 4, mantissas 3)."""
    cfg = preset("paper").replace(
        **{"preprocess.image_size": 2, "preprocess.patch_size": 1, "network.n_inputs": 4, "network.n_neurons": 3}
    )
    return FixedPointModel(
        bits=4,
        weight_mantissa=np.full((4, 3), 3, dtype=np.int32),
        scale_multiplier=np.ones(3, dtype=np.int32),
        scale_exponent=-8,
        threshold=np.full(3, 4, dtype=np.int32),
        decay_dv=400,
        config=cfg,
        calibration=np.zeros((3, 1), dtype=np.int64),
        float_calibration=np.zeros((3, 1), dtype=np.int64),
        reference_place_ids=np.zeros(1, dtype=np.int64),
        reference_traversals=["summer"],
        quantisation={"per_neuron": True},
        source_sha256="0" * 64,
    )


def _image_route(folder: Path, n: int = 12) -> Path:
    """The synthetic route's summer and winter images as PNG files under ``folder`` (read as pixels, as a peer's
    loader or a frame folder reads them), with ``places.csv`` and a ``subset.csv`` of every place; returns ``folder``."""
    import cv2  # only the tests that write image files need OpenCV

    route = synthetic_route(n, ("summer", "winter"))
    for name in ("summer", "winter"):
        (folder / name).mkdir(parents=True)
        for index, image in enumerate(route[name]):
            cv2.imwrite(str(folder / name / f"{index}.png"), image)
    rows = "".join(f"{i},summer/{i}.png,winter/{i}.png\n" for i in range(n))
    (folder / "places.csv").write_text("place_id,summer,winter\n" + rows, encoding="utf-8")
    (folder / "subset.csv").write_text("place_id\n" + "".join(f"{i}\n" for i in range(n)), encoding="utf-8")
    return folder


@pytest.fixture
def image_route():
    """The factory ``image_route(folder, n=12) -> folder``: the synthetic route written as PNG files with its
    place manifest (``places.csv``) and a subset file (``subset.csv``)."""
    return _image_route


@pytest.fixture
def small_config():
    """The factory ``small_config(n_inputs=16, n_neurons=6, **overrides) -> Config``."""
    return _small_config


@pytest.fixture
def make_model():
    """The factory ``make_model(rng, *, bits, wta, dv, uniform, n_inputs, n_neurons) -> FixedPointModel``."""
    return _make_model
