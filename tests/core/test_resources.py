"""Memory limits as stated errors (src/vprsnn_export/resources.py): the need is predicted and checked before allocating."""

from __future__ import annotations

import numpy as np
import pytest

import vprsnn_export as vx
from vprsnn_export import cli, resources
from vprsnn_export.data.encoding import query_spikes
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.resources import (
    ENV_LIMIT,
    MemoryNeed,
    available_memory,
    check_memory,
    format_size,
    memory_limit,
    parse_size,
    run_need,
    set_memory_limit,
    training_need,
)

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(autouse=True)
def default_limit(monkeypatch):
    monkeypatch.delenv(ENV_LIMIT, raising=False)
    set_memory_limit(None)
    yield
    set_memory_limit(None)


@pytest.mark.parametrize(
    ("text", "size"),
    [
        ("512", 512),
        ("1K", 1024),
        ("1.5k", 1536),
        ("8G", 8 << 30),
        ("2 GiB", 2 << 30),
        ("1T", 1 << 40),
        ("3MB", 3 << 20),
    ],
)
def test_parse_size(text, size):
    assert parse_size(text) == size


@pytest.mark.parametrize("text", ["", "x", "-1G", "0", "0.1", "1e9", "²G", "８G", "1_000", "8Q", "G", None, 8])
def test_parse_size_refuses(text):
    with pytest.raises(InvalidValueError, match="--memory-limit"):
        parse_size(text)


def test_format_size():
    assert format_size(512) == "512 B"
    assert format_size(3 << 30) == "3.0 GiB"
    assert format_size(1536) == "1.5 KiB"


def test_available_memory_reads_meminfo():
    text = "MemTotal:       24684096 kB\nMemFree: 1 kB\nMemAvailable:   2048 kB\n"
    assert available_memory(text) == 2048 * 1024
    assert available_memory("no such line") is None or available_memory("no such line") > 0  # sysconf fallback


def test_limit_precedence(monkeypatch):
    monkeypatch.setattr(resources, "available_memory", lambda: 1000)
    assert memory_limit() == 900  # 90 % of the available memory
    monkeypatch.setenv(ENV_LIMIT, "2K")
    assert memory_limit() == 2048
    assert set_memory_limit("1M") == 1 << 20  # the option wins over the environment
    assert set_memory_limit(None) == 2048
    monkeypatch.setenv(ENV_LIMIT, "lots")
    with pytest.raises(InvalidValueError, match=ENV_LIMIT):
        memory_limit()
    monkeypatch.delenv(ENV_LIMIT)
    for bad in (0, -5, True, 1.5):
        with pytest.raises(InvalidValueError, match="memory limit"):
            set_memory_limit(bad)


def test_run_need_terms():
    need = run_need(presentations=3, timesteps=10, n_inputs=4, n_neurons=5, places=6, chunk=2, rate_scale=0.5)
    sizes = dict(need.terms)
    assert sizes["input spikes 3 x 10 x 4"] == 120
    assert sizes["spike lists"] == 4 * 2 * 10 * 4 // 2
    assert need.total == 120 + 160 + 4 * 4 * 5 * 2 + 8 * 5 * (3 + 6) + 8 * 3 * 6 * 4
    recorded = run_need(presentations=3, timesteps=10, n_inputs=4, n_neurons=5, places=6, chunk=2, rasters=2)
    assert dict(recorded.terms)["raster 3 x 10 x 5"] == 2 * 3 * 10 * 5


def test_a_long_route_run_in_blocks_needs_a_blocks_spikes_and_sparse_counts():
    sizes = {"presentations": 27000, "timesteps": 80, "n_inputs": 1568, "n_neurons": 27000, "places": 27000}
    whole = dict(run_need(**sizes, chunk=128, readout_rows=1034).terms)
    blocks = dict(run_need(**sizes, chunk=128, readout_rows=1034, block=1024).terms)
    assert whole["input spikes 27000 x 80 x 1568"] == 27000 * 80 * 1568
    assert blocks["input spikes 1024 x 80 x 1568"] == 1024 * 80 * 1568
    assert blocks["counts and S^R (27000 neurons, sparse)"] == 12 * 80 * (2 * 27000 + 27000)
    assert blocks["counts of a block 1024 x 27000"] == 8 * 1024 * 27000
    assert sum(blocks.values()) < sum(whole.values()) / 8  # 1.6 GiB against 14.4


def test_training_need_grows_with_modules_and_threads():
    one = training_need(n_modules=1, n_inputs=10, n_neurons=4, timesteps=5, batch=2, threads=1).total
    assert training_need(n_modules=2, n_inputs=10, n_neurons=4, timesteps=5, batch=2, threads=1).total > one
    assert training_need(n_modules=1, n_inputs=10, n_neurons=4, timesteps=5, batch=2, threads=2).total > one


def test_check_memory_states_size_limit_and_option():
    need = MemoryNeed((("big", 3 << 30), ("small", 1 << 20)))
    check_memory(need, "step", "less", limit=4 << 30)
    with pytest.raises(InvalidValueError) as raised:
        check_memory(need, "step", "fewer things", limit=1 << 30)
    message = str(raised.value)
    assert "\n" not in message
    assert "3.0 GiB" in message and "big" in message and "1.0 GiB" in message and "fewer things" in message
    set_memory_limit("1G")
    with pytest.raises(InvalidValueError, match="set by --memory-limit"):
        check_memory(need, "step", "less")


def test_encoding_checks_before_allocating():
    cfg = vx.Config().replace(**{"encoder.timesteps": 100_000})
    images = np.zeros((300, cfg.network.n_inputs), dtype=np.float32)
    set_memory_limit("8G")  # the raster alone would be 300 x 100000 x 1568 bytes = 44 GiB
    with pytest.raises(InvalidValueError, match="input spikes 300 x 100000 x 1568"):
        query_spikes(images, np.arange(300), "winter", cfg)


def test_train_and_calibrate_refuses_a_million_neurons_before_training():
    cfg = vx.Config().replace(**{"network.n_neurons": 1_000_000, "encoder.timesteps": 8, "train.epochs": 1})
    data = vx.load_dataset("synthetic:4", ["summer"], cfg.preprocess)
    set_memory_limit("8G")
    with pytest.raises(InvalidValueError, match=r"training needs about .* over the limit of 8\.0 GiB.*--neurons"):
        vx.train_and_calibrate(data, ["summer"], cfg, progress=False)


def test_evaluate_refuses_a_run_over_the_limit(tiny_model):
    images = np.zeros((4, tiny_model.config.network.n_inputs), dtype=np.float32)
    set_memory_limit(1024)
    with pytest.raises(InvalidValueError, match="evaluation needs about"):
        vx.evaluate_fixed_point(tiny_model, images, np.arange(4), "winter", vx.SequenceOptions())


def test_cli_states_the_limit(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    argv = ["train", "--data", "synthetic:10", "--reference", "summer", "--timesteps", "20", "--epochs", "1"]
    assert cli.main([*argv, "--neurons", "1000000", "--out", "a.npz", "--memory-limit", "8G", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: training needs about") and "--memory-limit" in err[0]
    assert not (tmp_path / "a.npz").exists()
    assert cli.main([*argv, "--neurons", "8", "--out", "b.npz", "--memory-limit", "lots"]) == 2
    assert (
        capsys.readouterr().err.strip() == "error: --memory-limit: expected a size such as 512M, 8G or 1.5T, got 'lots'"
    )
