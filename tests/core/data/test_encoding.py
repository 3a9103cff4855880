import numpy as np
import torch

from vprsnn_export.config import EncoderConfig
from vprsnn_export.data.encoding import encode, encode_presentations, presentation_seed


def test_spikes_are_a_pure_function_of_seed_image_and_presentation():
    cfg = EncoderConfig(rate_scale=0.25, timesteps=50)
    images = np.random.default_rng(0).random((4, 784)).astype(np.float32)
    ids = np.array([3, 7, 11, 12])
    full = encode_presentations(images, ids, cfg, seed=1, stream="query", traversal="winter")
    alone = encode_presentations(images[2:3], ids[2:3], cfg, seed=1, stream="query", traversal="winter")
    assert torch.equal(full[2], alone[0])
    again = encode_presentations(images, ids, cfg, seed=1, stream="query", traversal="winter")
    assert torch.equal(full, again)
    other = encode_presentations(images, ids, cfg, seed=1, stream="calibrate", traversal="winter")
    assert not torch.equal(full, other)


def test_rate_matches_clipped_probability():
    cfg = EncoderConfig(rate_scale=0.25, timesteps=4000)
    images = np.array([[0.0, 0.4, 1.0, 8.0]], dtype=np.float32)
    spikes = encode(images, [presentation_seed(0, "s", "t", 0)], cfg)
    rates = spikes.float().mean(dim=1)[0].numpy()
    assert rates[0] == 0.0
    np.testing.assert_allclose(rates[1:], [0.1, 0.25, 1.0], atol=0.02)
    assert spikes.dtype == torch.uint8 and spikes.shape == (1, 4000, 4)


def torch_reference(prob: np.ndarray, seeds: list[int], timesteps: int) -> torch.Tensor:
    """The encoder as first written: torch.rand per row from its own generator, then u < p."""
    out = torch.empty((len(seeds), timesteps, prob.shape[1]), dtype=torch.uint8)
    for row, seed in enumerate(seeds):
        uniforms = torch.rand((timesteps, prob.shape[1]), generator=torch.Generator().manual_seed(seed))
        out[row] = uniforms < torch.from_numpy(prob[row])
    return out


def test_compiled_encoder_reproduces_torch_rand_bit_for_bit():
    rng = np.random.default_rng(3)
    prob = rng.random((6, 97)).astype(np.float32)
    prob[0, :6] = [0.0, 1.0, 2.0**-24, 1.0 - 2.0**-24, 0.5, np.nextafter(np.float32(0.5), np.float32(1))]
    prob[1] = np.round(prob[1] * 2**24) / 2**24  # exactly on the grid of the uniforms: u < p is strict
    seeds = [0, 1, 2**32 + 5, (1 << 63) - 1, presentation_seed(42, "train", "summer", 7, 3), 123456789]
    for timesteps in (1, 7, 300):  # 7 x 97 and 300 x 97 cross the 624-draw blocks of MT19937
        expected = torch_reference(prob, seeds, timesteps)
        cfg = EncoderConfig(rate_scale=1.0, timesteps=timesteps)
        assert torch.equal(encode(prob, seeds, cfg), expected)
