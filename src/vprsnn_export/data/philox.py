"""The counter-based encoder (``encoder.generator = "philox"``): the same spikes on the CPU and on any torch device.

Philox4x32-10 (Salmon et al., SC'11, "Parallel random numbers: as easy as 1, 2, 3"; Random123) maps a 128-bit
counter c and a 64-bit key k to four 32-bit words in ten rounds of

    (hi_0, lo_0) = M_0 c_0,  (hi_1, lo_1) = M_1 c_2          (32 x 32 -> 64-bit products)
    c <- (hi_1 ^ c_1 ^ k_0, lo_1, hi_0 ^ c_3 ^ k_1, lo_0),   k <- (k_0 + W_0, k_1 + W_1) mod 2^32

with M = (0xD2511F53, 0xCD9E8D57), W = (0x9E3779B9, 0xBB67AE85). A presentation's key is its 63-bit presentation
seed (low word k_0, high word k_1); its draw j = t D + i is word j mod 4 of counter (j div 4, 0, 0, 0), and

    s[t, i] = (x_j >> 8) < ceil(p_i 2^24)

(the top 24 bits, u = (x_j >> 8) / 2^24, compared as :mod:`.encoding_kernel` compares MT19937's). Every draw is a
pure function of (seed, t, i), so the spikes are integer arithmetic that every device computes alike:
:func:`philox_block_words` runs it in numba on the CPU (the encoder and the training kernel), :func:`philox_spikes` in
torch int64 operations on the tensors' own device (a GPU draws its training batches in place, no host copy), and
both give the same bits (tests/core/data/test_philox.py, with Random123's known-answer vectors).
"""

from __future__ import annotations

import numpy as np
import torch

from ..network.kernel_sums import compiled

M0, M1 = 0xD2511F53, 0xCD9E8D57  # the round multipliers
W0, W1 = 0x9E3779B9, 0xBB67AE85  # the key schedule's Weyl increments
ROUNDS = 10
WORD = 0xFFFFFFFF
SHIFT = 8  # u = (x >> 8) / 2^24: the top 24 bits of each 32-bit word
#: Draws (rows x T x D) of one torch pass on the CPU, and on a GPU: its int64 intermediates stay near 100 MB and
#: 2 GB (few passes: each is about 150 kernel launches).
TORCH_DRAWS = 1 << 21
DEVICE_DRAWS = 1 << 26


@compiled
def philox_block_words(first: int, c1: int, c2: int, c3: int, k0: int, k1: int, blocks: int, words: np.ndarray) -> None:
    """words[4 b + l] = word l of Philox4x32-10 at counter ((first + b) mod 2^32, c1, c2, c3) and key (k0, k1), b < ``blocks``
    (32-bit words; the encoder's counters are (b, 0, 0, 0))."""
    word = np.uint64(WORD)
    for b in range(blocks):
        x0, x1 = np.uint64(first + b) & word, np.uint64(c1) & word
        x2, x3 = np.uint64(c2) & word, np.uint64(c3) & word
        key0, key1 = np.uint64(k0) & word, np.uint64(k1) & word
        for _ in range(ROUNDS):
            p0, p1 = np.uint64(M0) * x0, np.uint64(M1) * x2
            y0 = (p1 >> np.uint64(32)) ^ x1 ^ key0
            y2 = (p0 >> np.uint64(32)) ^ x3 ^ key1
            x0, x1, x2, x3 = y0, p1 & word, y2, p0 & word
            key0, key1 = (key0 + np.uint64(W0)) & word, (key1 + np.uint64(W1)) & word
        words[4 * b], words[4 * b + 1], words[4 * b + 2], words[4 * b + 3] = x0, x1, x2, x3


@compiled
def _philox_rows(thresholds: np.ndarray, seeds: np.ndarray, timesteps: int, out: np.ndarray) -> None:
    """out[n, t, i] = (x_{t D + i} >> 8) < thresholds[n, i], x the Philox4x32-10 words of key seeds[n]: a row's
    words first, then compared step by step (vectorised, 5-8x faster than word by word)."""
    n_rows, n_inputs = thresholds.shape
    blocks = (timesteps * n_inputs + 3) // 4
    words = np.empty(4 * blocks, dtype=np.uint32)
    for r in range(n_rows):
        philox_block_words(0, 0, 0, 0, seeds[r] & WORD, (seeds[r] >> 32) & WORD, blocks, words)
        limit = thresholds[r]
        for t in range(timesteps):
            row, target = words[t * n_inputs : (t + 1) * n_inputs], out[r, t]
            for i in range(n_inputs):
                target[i] = np.int64(row[i] >> np.uint32(SHIFT)) < limit[i]


def _mulhilo(a: torch.Tensor, b: int) -> tuple[torch.Tensor, torch.Tensor]:
    """(hi, lo) 32-bit words of a b (a < 2^32 in int64, b < 2^32), from 16-bit halves of a: no int64 overflows.

    With h = (a >> 16) b and l = (a & 0xFFFF) b (each < 2^48): hi = (h + (l >> 16)) >> 16, lo = ((h mod 2^16) 2^16 + l)
    mod 2^32."""
    high, low = (a >> 16) * b, (a & 0xFFFF) * b
    return (high + (low >> 16)) >> 16, (((high & 0xFFFF) << 16) + low) & WORD


def philox4x32(counter: tuple[torch.Tensor, ...], key: tuple[torch.Tensor, torch.Tensor]) -> tuple[torch.Tensor, ...]:
    """Philox4x32-10 of four int64 counter words and two key words (each < 2^32, broadcast), in torch operations."""
    c0, c1, c2, c3 = counter
    k0, k1 = key
    for _ in range(ROUNDS):
        (hi0, lo0), (hi1, lo1) = _mulhilo(c0, M0), _mulhilo(c2, M1)
        c0, c1, c2, c3 = hi1 ^ c1 ^ k0, lo1, hi0 ^ c3 ^ k1, lo0
        k0, k1 = (k0 + W0) & WORD, (k1 + W1) & WORD
    return c0, c1, c2, c3


def philox_spikes(limits: torch.Tensor, seeds: torch.Tensor, timesteps: int) -> torch.Tensor:
    """Spikes (N, T, D) uint8 on ``limits``' device: s[n, t, i] = (x_{t D + i} >> 8) < limits[n, i] (module
    docstring), ``limits`` (N, D) the thresholds ceil(p 2^24) and ``seeds`` (N,) int64 the presentation seeds;
    the same bits as the CPU encoder's (:func:`_philox_rows`), drawn :data:`TORCH_DRAWS` (a GPU: :data:`DEVICE_DRAWS`)
    at a time."""
    n, d = limits.shape
    total, device = timesteps * d, limits.device
    blocks = torch.arange((total + 3) // 4, device=device, dtype=torch.int64)
    zero = torch.zeros_like(blocks)
    out = torch.empty((n, timesteps, d), dtype=torch.uint8, device=device)
    seeds = seeds.to(device=device, dtype=torch.int64)
    rows = max(1, (TORCH_DRAWS if device.type == "cpu" else DEVICE_DRAWS) // max(total, 1))
    for first in range(0, n, rows):
        part = seeds[first : first + rows, None]
        words = philox4x32((blocks & WORD, blocks >> 32, zero, zero), (part & WORD, (part >> 32) & WORD))
        draws = torch.stack(words, dim=-1).reshape(len(part), -1)[:, :total] >> SHIFT
        below = draws.reshape(len(part), timesteps, d) < limits[first : first + rows, None, :].to(torch.int64)
        out[first : first + rows] = below.to(torch.uint8)
    return out
