"""The counter-based encoder (``encoder.generator = "philox"``): Random123's known answers, one set of bits on the CPU
kernels and in torch on any device, and the training paths fed the same spikes."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vprsnn_export.config import Config, preset
from vprsnn_export.data import philox
from vprsnn_export.data.encoding import encode
from vprsnn_export.data.encoding_kernel import bernoulli_limits, generator_seeds
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.trainer import batched
from vprsnn_export.trainer.batched import device_spikes, module_training_rows, train_modules
from vprsnn_export.trainer.train import Presentation

#: Random123 tests/kat_vectors, the three "philox4x32 10" lines: counter (4 words), key (2), the result (4).
KNOWN_ANSWERS = [
    ((0, 0, 0, 0), (0, 0), (0x6627E8D5, 0xE169C58D, 0xBC57AC4C, 0x9B00DBD8)),
    ((0xFFFFFFFF,) * 4, (0xFFFFFFFF,) * 2, (0x408F276D, 0x41C83B0E, 0xA20BC7C6, 0x6D5451FD)),
    (
        (0x243F6A88, 0x85A308D3, 0x13198A2E, 0x03707344),
        (0xA4093822, 0x299F31D0),
        (0xD16CFE09, 0x94FDCCEB, 0x5001E420, 0x24126EA1),
    ),
]
CUDA = pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="torch sees no CUDA GPU"))


@pytest.mark.parametrize(("counter", "key", "expected"), KNOWN_ANSWERS)
def test_both_implementations_give_random123s_known_answers(counter, key, expected):
    words = np.zeros(8, dtype=np.uint32)
    philox.philox_block_words(*counter, *key, 2, words)  # and the counter after it, as the encoder runs them
    assert tuple(int(w) for w in words[:4]) == expected
    following = philox.philox4x32(
        (torch.tensor((counter[0] + 1) & 0xFFFFFFFF), *map(torch.tensor, counter[1:])),
        tuple(torch.tensor(k) for k in key),
    )
    assert tuple(int(w) for w in words[4:]) == tuple(int(w) for w in following)
    words = philox.philox4x32(tuple(torch.tensor(c) for c in counter), tuple(torch.tensor(k) for k in key))
    assert tuple(int(w) for w in words) == expected


def probabilities(rng: np.random.Generator, n: int, d: int) -> np.ndarray:
    p = rng.random((n, d)).astype(np.float32)
    p[0, :3] = [0.0, 1.0, 5.0]  # never, always, always (clipped to 1)
    return p


@pytest.mark.parametrize(("n", "timesteps", "d"), [(3, 7, 13), (2, 1, 3), (4, 5, 8)])
def test_the_cpu_encoder_draws_word_j_mod_4_of_counter_j_div_4_and_compares_its_top_24_bits(n, timesteps, d):
    rng = np.random.default_rng(n * timesteps * d)
    p = probabilities(rng, n, d)
    seeds = [int(s) for s in rng.integers(0, 2**63, n, dtype=np.int64)]
    spikes = encode(
        p, seeds, preset("paper").encoder.__class__(timesteps=timesteps, rate_scale=1.0, generator="philox")
    )
    limits = bernoulli_limits(np.clip(p, 0, 1))
    for r, seed in enumerate(seeds):
        for j in range(timesteps * d):
            words = philox.philox4x32(
                (torch.tensor(j // 4), *(torch.tensor(0),) * 3),
                (torch.tensor(seed & 0xFFFFFFFF), torch.tensor(seed >> 32)),
            )
            assert spikes[r, j // d, j % d] == ((int(words[j % 4]) >> 8) < limits[r, j % d])
    assert not spikes[0, :, 0].any() and spikes[0, :, 1:3].all()


@pytest.mark.parametrize("device", ["cpu", CUDA])
def test_torch_draws_the_cpu_encoders_bits_on_any_device_in_any_chunking(device, monkeypatch):
    rng = np.random.default_rng(5)
    p = probabilities(rng, 9, 51)  # 51 inputs x 7 steps: a last counter with one word used
    seeds = [int(s) for s in rng.integers(0, 2**63, 9, dtype=np.int64)]
    cfg = preset("paper").encoder.__class__(timesteps=7, rate_scale=1.0, generator="philox")
    cpu = encode(p, seeds, cfg)
    limits = torch.from_numpy(bernoulli_limits(np.clip(p, 0, 1))).to(device)
    for draws in (philox.TORCH_DRAWS, 7 * 51, 1):  # all rows at once, one row at a time
        monkeypatch.setattr(philox, "TORCH_DRAWS", draws)
        drawn = philox.philox_spikes(limits, torch.from_numpy(generator_seeds(seeds, "philox")), 7)
        assert drawn.device.type == device and drawn.dtype == torch.uint8
        assert torch.equal(drawn.cpu(), cpu)


def test_philox_spikes_fire_at_their_rate_depend_on_their_seed_alone_and_differ_from_mt19937s():
    cfg = preset("lean").encoder
    philox_cfg = cfg.__class__(timesteps=cfg.timesteps, rate_scale=cfg.rate_scale, generator="philox")
    images = np.full((4, 1568), 0.5, dtype=np.float32)
    spikes = encode(images, [11, 12, 13, 14], philox_cfg)
    rate = float(spikes.float().mean())
    p = cfg.rate_scale * 0.5
    assert abs(rate - p) < 4 * np.sqrt(p * (1 - p) / spikes.numel())
    assert torch.equal(encode(images[2:3], [13], philox_cfg)[0], spikes[2])  # a row is its seed's alone
    assert not torch.equal(spikes[0], spikes[1])
    assert not torch.equal(spikes, encode(images, [11, 12, 13, 14], cfg))


def test_the_generator_is_a_config_key_written_only_when_it_is_not_the_default():
    assert "generator" not in Config().to_dict()["encoder"]  # every file written before it: the same bytes
    cfg = Config().replace(**{"encoder.generator": "philox"})
    assert cfg.to_dict()["encoder"]["generator"] == "philox"
    assert Config.from_dict(cfg.to_dict()) == cfg
    assert cfg.training_encoder.generator == "philox"
    with pytest.raises(InvalidValueError, match=r"encoder\.generator: 'pcg' is not one of mt19937, philox"):
        Config().replace(**{"encoder.generator": "pcg"})


@pytest.mark.usefixtures("one_thread")
@pytest.mark.parametrize("device", ["cpu", CUDA])
def test_the_compiled_kernel_and_the_torch_loop_train_on_the_same_philox_spikes(device, monkeypatch):
    """The kernel draws each batch inside itself on the CPU; the torch loop draws it on its device: the same spikes
    (counted), so the two trainings agree as the MT19937 ones do, to float32 rounding."""
    small = {"network.n_neurons": 12, "train.timesteps": 10, "train.epochs": 2, "train.batch_size": 8}
    cfg = preset("paper").replace(**small, **{"train.module_size": 16, "encoder.generator": "philox"})
    images = np.random.default_rng(3).random((32, 784)).astype(np.float32)
    presentations = [Presentation("summer", p) for p in range(32)]
    rows = module_training_rows(32, 16, 1)
    drawn: list[torch.Tensor] = []
    real = batched.device_spikes

    def recorded(images, seeds, cfg, device):
        drawn.append(real(images, seeds, cfg, device))
        return drawn[-1]

    monkeypatch.setattr(batched, "device_spikes", recorded)
    loop = train_modules(images, presentations, rows, cfg, device=torch.device(device), progress=False, compiled=False)
    kernel = train_modules(images, presentations, rows, cfg, device=torch.device("cpu"), progress=False)
    assert len(drawn) == 2 * 2 and all(s.device.type == device for s in drawn)  # epochs x batches: every module at once
    assert all(s.shape == (2 * 8, 10, 784) for s in drawn)
    seeds = [int(s) for s in generator_seeds(range(8), "philox")]
    assert torch.equal(
        device_spikes(images[:8], seeds, cfg, torch.device("cpu")), encode(images[:8], seeds, cfg.training_encoder)
    )
    torch.testing.assert_close(loop.weights.cpu(), kernel.weights, rtol=0, atol=1e-5)
    torch.testing.assert_close(loop.thresholds.cpu(), kernel.thresholds, rtol=0, atol=1e-5)
