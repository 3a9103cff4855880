"""The compiled Bernoulli encoder: ``torch.rand(...) < p`` bit for bit, without building the uniforms.

torch's CPU generator is MT19937 seeded with the seed's low 32 bits, and a float32 uniform is u = m / 2^24 with m
the low 24 bits of one 32-bit draw, so u < p iff m < ceil(p 2^24): the kernel (:func:`_bernoulli_kernel`, checked
entry point :func:`bernoulli_kernel`) runs the twister and compares integers, for :mod:`vprsnn_export.data.encoding`
and inside the training kernel (:mod:`vprsnn_export.trainer.stdp_kernel`, each module's batch in one call); with
``encoder.generator = "philox"`` the same kernels draw Philox4x32-10's words instead (:mod:`.philox`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..network.kernel_checks import require_array, require_int
from ..network.kernel_sums import SPIKES, compiled
from .philox import _philox_rows

MT_N = 624  # words of the Mersenne Twister state (torch's CPU generator is MT19937)
MT_M = 397
MANTISSA_BITS = 24  # torch.rand(float32) keeps the low 24 bits of one 32-bit draw: u = (r & (2^24 - 1)) / 2^24


@compiled
def _mt_seed(seed: int, state: np.ndarray) -> None:
    """torch's ``mt19937(seed)``: x_0 = seed mod 2^32, x_j = 1812433253 (x_{j-1} ^ (x_{j-1} >> 30)) + j mod 2^32."""
    state[0] = np.uint32(seed & 0xFFFFFFFF)
    for j in range(1, MT_N):
        prev = np.uint64(state[j - 1])
        mixed = np.uint64(1812433253) * (prev ^ (prev >> np.uint64(30))) + np.uint64(j)
        state[j] = np.uint32(mixed & np.uint64(0xFFFFFFFF))


@compiled
def _mt_mantissas(state: np.ndarray, out: np.ndarray) -> None:
    """The next 624 draws of MT19937 (twist, then tempering), each reduced to its low 24 bits, into out[:624]."""
    upper = np.uint32(0x80000000)
    lower = np.uint32(0x7FFFFFFF)
    matrix = np.uint32(0x9908B0DF)
    one = np.uint32(1)
    for j in range(MT_N - MT_M):
        y = (state[j] & upper) | (state[j + 1] & lower)
        state[j] = state[j + MT_M] ^ (y >> one) ^ (matrix * (y & one))
    for j in range(MT_N - MT_M, MT_N - 1):
        y = (state[j] & upper) | (state[j + 1] & lower)
        state[j] = state[j + MT_M - MT_N] ^ (y >> one) ^ (matrix * (y & one))
    y = (state[MT_N - 1] & upper) | (state[0] & lower)
    state[MT_N - 1] = state[MT_M - 1] ^ (y >> one) ^ (matrix * (y & one))
    for j in range(MT_N):
        y = state[j]
        y ^= y >> np.uint32(11)
        y ^= (y << np.uint32(7)) & np.uint32(0x9D2C5680)
        y ^= (y << np.uint32(15)) & np.uint32(0xEFC60000)
        y ^= y >> np.uint32(18)
        out[j] = np.int32(y & np.uint32(0xFFFFFF))


@compiled
def _bernoulli_kernel(thresholds: np.ndarray, seeds: np.ndarray, timesteps: int, out: np.ndarray) -> None:
    """out[n, t, i] = m_n[t D + i] < thresholds[n, i], m_n the 24-bit draws of MT19937 seeded with seeds[n]."""
    n_rows, n_inputs = thresholds.shape
    total = timesteps * n_inputs
    state = np.empty(MT_N, dtype=np.uint32)
    draws = np.empty(total + MT_N, dtype=np.int32)
    for r in range(n_rows):
        _mt_seed(seeds[r], state)
        for start in range(0, total, MT_N):
            _mt_mantissas(state, draws[start : start + MT_N])
        limit = thresholds[r]
        for t in range(timesteps):
            row, target = draws[t * n_inputs : (t + 1) * n_inputs], out[r, t]
            for i in range(n_inputs):
                target[i] = row[i] < limit[i]


@compiled
def _encode_rows(thresholds: np.ndarray, seeds: np.ndarray, timesteps: int, out: np.ndarray, philox: bool) -> None:
    """out[n] = row n's spikes from MT19937 (:func:`_bernoulli_kernel`) or, with ``philox``, Philox4x32-10."""
    if philox:
        _philox_rows(thresholds, seeds, timesteps, out)
    else:
        _bernoulli_kernel(thresholds, seeds, timesteps, out)


def bernoulli_kernel(
    thresholds: np.ndarray, seeds: np.ndarray, timesteps: int, out: np.ndarray, philox: bool = False
) -> None:
    """:func:`_encode_rows` once its arrays are checked (InvalidValueError naming them)."""
    k = "Bernoulli kernel"
    require_array(k, "thresholds", thresholds, (np.int32,), (None, None))
    n_rows, n_inputs = thresholds.shape
    require_array(k, "seeds", seeds, (np.int64,), (n_rows,))
    steps = require_int(k, "timesteps", timesteps, 0)
    require_array(k, "out", out, SPIKES, (n_rows, steps, n_inputs), writable=True)
    _encode_rows(thresholds, seeds, steps, out, bool(philox))


def bernoulli_spikes(prob: np.ndarray, seeds: Sequence[int], timesteps: int, generator: str = "mt19937") -> np.ndarray:
    """Spikes (N, T, D) uint8 with s[n, t, i] = u[n, t, i] < p[n, i], bit for bit
    ``torch.rand((T, D), generator=torch.Generator().manual_seed(seeds[n])) < p[n]`` (about 13x faster, as
    u < p iff m < ceil(p 2^24): module docstring; NaN never fires, as u < NaN is false); with ``generator``
    ``"philox"`` u is Philox4x32-10's (:mod:`.philox`)."""
    p = np.asarray(prob, dtype=np.float32)  # (N, D) and N seeds: checked by the caller, encode
    limits = bernoulli_limits(p)
    out = np.empty((p.shape[0], int(timesteps), p.shape[1]), dtype=np.uint8)
    bernoulli_kernel(limits, generator_seeds(seeds, generator), int(timesteps), out, generator == "philox")
    return out


def bernoulli_limits(prob: np.ndarray) -> np.ndarray:
    """The integer thresholds ceil(p 2^24), clipped to [0, 2^24], int32: u < p iff m < ceil(p 2^24) (NaN: 0)."""
    p = np.asarray(prob, dtype=np.float32)
    scaled = np.ceil(np.nan_to_num(p.astype(np.float64), nan=0.0) * float(1 << MANTISSA_BITS))
    return np.ascontiguousarray(np.clip(scaled, 0, 1 << MANTISSA_BITS), dtype=np.int32)


def generator_seeds(seeds: Sequence[int], generator: str = "mt19937") -> np.ndarray:
    """The seeds as the generator uses them, int64: torch's CPU generator their low 32 bits, Philox all 63."""
    mask = 0xFFFFFFFF if generator == "mt19937" else (1 << 63) - 1
    return np.array([int(s) & mask for s in seeds], dtype=np.int64)
