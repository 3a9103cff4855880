import numpy as np
import torch

from vprsnn_export.config import EncoderConfig
from vprsnn_export.encoding import encode, encode_presentations, presentation_seed


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
