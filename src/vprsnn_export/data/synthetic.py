"""A deterministic synthetic train route: the embedded default data set (``--data synthetic``).

It is *not* real data. It models what makes Nordland-style place recognition work and fail, so the whole
pipeline can be demonstrated and tested without a download:

* One long panorama ``L(y, x)`` (36 rows, padded around the 32 visible ones) is rendered from smooth
  low-frequency noise (sky, terrain), a skyline ``s(x)`` (ground where ``y >= s(x)``), blurred random blobs
  (vegetation, rocks) and sharp structures (catenary poles, buildings, a track band).
* Place ``i`` is the 64 x 32 window whose left edge is at ``x = i * STRIDE``: consecutive places overlap (a
  train moving) and look alike, distant ones differ.
* Each traversal (season) rescales the vegetation blobs, brightens and flattens the terrain (snow), then maps
  each pixel in [0, 1] to ``v' = clip(gain * (contrast * (v - 1/2) + 1/2) ** gamma + offset + n, 0, 1)``
  with Gaussian noise ``n`` and shifts each image by a few pixels; ``summer`` is the clean rendering.

Every random number comes from ``np.random.default_rng`` seeded with ``seed``, a layer or season code and a
chunk or place index: the output is reproducible bit for bit, and place ``i`` does not depend on ``n_places``
(``synthetic_route(100)`` starts with ``synthetic_route(60)``).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from ..errors import InvalidValueError

SYNTHETIC_VERSION = 1
IMAGE_HEIGHT = 32
IMAGE_WIDTH = 64
STRIDE = 12  # pixels of panorama between consecutive places
DEFAULT_PLACES = 60
DEFAULT_TRAVERSALS = ("summer", "winter")

_PAD = 3  # panorama margin on every side, room for the per-image shift
_HEIGHT = IMAGE_HEIGHT + 2 * _PAD
_CHUNK = 256  # panorama columns rendered from one random stream
_BLOBS_PER_CHUNK = 40
_POLES_PER_CHUNK = 5
_BUILDINGS_PER_CHUNK = 2


@dataclass(frozen=True)
class Season:
    """Appearance of one traversal (see the module docstring for the per-pixel equation)."""

    code: int  # stable id used in seeds; never reuse one
    blob_spread: float  # per-blob amplitude multiplier ~ N(1, blob_spread)
    snow: float  # terrain v <- (1 - snow) * v + snow * 0.85
    gain: float
    offset: float
    gamma: float
    contrast: float
    foliage: float  # std of a season-specific fine texture added to the terrain
    noise: float  # std of additive Gaussian noise, in [0, 1] units
    shift: int  # max |dx|, |dy| in pixels


SEASONS: dict[str, Season] = {  # code, blob_spread, snow, gain, offset, gamma, contrast, foliage, noise, shift
    "summer": Season(0, 0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0),
    "winter": Season(1, 0.6, 0.55, 0.95, 0.05, 0.8, 0.8, 0.06, 0.05, 2),
    "spring": Season(2, 0.4, 0.0, 1.0, 0.02, 0.9, 0.9, 0.06, 0.04, 2),
    "fall": Season(3, 0.5, 0.0, 0.85, 0.0, 1.2, 1.1, 0.08, 0.045, 2),
}
SYNTHETIC_TRAVERSALS = tuple(SEASONS)

# Layer codes for the random streams of the shared (season-independent) panorama.
_SKYLINE, _TERRAIN, _SKY, _BLOBS, _POLES, _BUILDINGS, _TEXTURE = range(7)
_SEASON_STREAM = 100
_IMAGE_STREAM = 1000


def synthetic_fingerprint(
    n_places: int = DEFAULT_PLACES, traversals: tuple[str, ...] = DEFAULT_TRAVERSALS, seed: int = 0
) -> str:
    """sha256 hex of ``"vprsnn-synthetic-route|v=<VERSION>|places=<N>|traversals=<a,b>|seed=<seed>"``."""
    canonical = f"vprsnn-synthetic-route|v={SYNTHETIC_VERSION}|places={int(n_places)}|traversals={','.join(traversals)}|seed={int(seed)}"
    return hashlib.sha256(canonical.encode("utf-8")).hexdigest()


def synthetic_route(
    n_places: int = DEFAULT_PLACES, traversals: tuple[str, ...] = DEFAULT_TRAVERSALS, seed: int = 0
) -> dict[str, np.ndarray]:
    """Render ``n_places`` places of every traversal: name -> ``(n_places, 32, 64)`` uint8 images."""
    if isinstance(n_places, bool) or not isinstance(n_places, (int, np.integer)) or n_places < 1:
        raise InvalidValueError(f"the synthetic route needs a positive number of places, got {n_places!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InvalidValueError(f"the synthetic route seed must be a non-negative integer, got {seed!r}")
    unknown = [name for name in traversals if name not in SEASONS]
    if unknown or not traversals:
        raise InvalidValueError(
            f"unknown synthetic traversal(s) {unknown}; available: {', '.join(SYNTHETIC_TRAVERSALS)}"
        )
    base = _render_base((n_places - 1) * STRIDE + IMAGE_WIDTH + 2 * _PAD, seed)
    return {name: _render_traversal(base, SEASONS[name], n_places, seed) for name in traversals}


@dataclass(frozen=True)
class _Base:
    """Season-independent layers of the panorama, all (_HEIGHT, width) float64 in ~[0, 1]."""

    sky: np.ndarray
    terrain: np.ndarray
    ground: np.ndarray  # bool mask y >= s(x)
    blobs: tuple[tuple[float, float, float, float, float, int], ...]  # (cy, cx, sy, sx, amplitude, chunk-local index)
    structures: np.ndarray  # NaN where no sharp structure, else its intensity


def _chunk_rng(seed: int, stream: int, chunk: int) -> np.random.Generator:
    return np.random.default_rng([seed, stream, chunk])


def _smoothstep(t: np.ndarray) -> np.ndarray:
    return t * t * (3.0 - 2.0 * t)


def _knot_chunks(width: int, spacing: int) -> int:
    """How many random streams of ``_CHUNK // spacing`` knots cover x = 0..width (plus the right neighbour)."""
    return -(-(width // spacing + 2) // (_CHUNK // spacing))


def _knots_1d(seed: int, stream: int, spacing: int, width: int, scale: float) -> np.ndarray:
    """Smooth 1-D noise: N(0, scale) knots every ``spacing`` px, smoothstep-interpolated, sampled at x = 0..width-1."""
    knots = np.concatenate(
        [_chunk_rng(seed, stream, c).normal(0.0, scale, _CHUNK // spacing) for c in range(_knot_chunks(width, spacing))]
    )
    x = np.arange(width) / spacing
    left = np.floor(x).astype(np.int64)
    t = _smoothstep(x - left)
    return knots[left] * (1.0 - t) + knots[left + 1] * t


def _knots_2d(seed: int, stream: int, spacing: tuple[int, int], width: int, scale: float) -> np.ndarray:
    """Smooth 2-D noise on a (_HEIGHT, width) grid: N(0, scale) knots, separable smoothstep interpolation."""
    sy, sx = spacing
    shape = (_HEIGHT // sy + 2, _CHUNK // sx)  # (knot rows, knots per random stream)
    knots = np.concatenate(
        [_chunk_rng(seed, stream, c).normal(0.0, scale, shape) for c in range(_knot_chunks(width, sx))], axis=1
    )
    y, x = np.arange(_HEIGHT) / sy, np.arange(width) / sx
    top, left = np.floor(y).astype(np.int64), np.floor(x).astype(np.int64)
    ty, tx = _smoothstep(y - top)[:, None], _smoothstep(x - left)[None, :]
    upper = knots[top][:, left] * (1.0 - tx) + knots[top][:, left + 1] * tx
    lower = knots[top + 1][:, left] * (1.0 - tx) + knots[top + 1][:, left + 1] * tx
    return upper * (1.0 - ty) + lower * ty


def _render_base(width: int, seed: int) -> _Base:
    y = np.arange(_HEIGHT, dtype=np.float64)[:, None]
    skyline = 15.0 + _knots_1d(seed, _SKYLINE, 32, width, 4.0) + _knots_1d(seed, _SKYLINE + 50, 4, width, 1.2)
    skyline = np.clip(skyline, _PAD + 4, _HEIGHT - 10)
    ground = y >= skyline[None, :]
    sky = 0.85 - 0.2 * (y / _HEIGHT) + _knots_2d(seed, _SKY, (12, 64), width, 0.06)
    terrain = (
        0.3
        + 0.2 * (y / _HEIGHT)
        + _knots_2d(seed, _TERRAIN, (6, 8), width, 0.1)
        + _knots_2d(seed, _TEXTURE, (3, 3), width, 0.06)
    )
    return _Base(sky, terrain, ground, _draw_blobs(width, seed), _draw_structures(width, seed))


def _draw_blobs(width: int, seed: int) -> tuple[tuple[float, float, float, float, float, int], ...]:
    blobs: list[tuple[float, float, float, float, float, int]] = []
    for chunk in range(width // _CHUNK + 2):
        rng = _chunk_rng(seed, _BLOBS, chunk)
        cx = rng.uniform(0, _CHUNK, _BLOBS_PER_CHUNK) + chunk * _CHUNK
        cy = rng.uniform(0, _HEIGHT, _BLOBS_PER_CHUNK)
        sx = rng.uniform(1.5, 6.0, _BLOBS_PER_CHUNK)
        sy = rng.uniform(1.0, 4.0, _BLOBS_PER_CHUNK)
        amplitude = rng.uniform(-0.3, 0.3, _BLOBS_PER_CHUNK)
        blobs.extend(zip(cy, cx, sy, sx, amplitude, range(_BLOBS_PER_CHUNK), strict=True))
    return tuple(blobs)


def _draw_structures(width: int, seed: int) -> np.ndarray:
    """Sharp-edged poles (dark vertical lines to the ground), buildings (flat rectangles) and a track band."""
    structures = np.full((_HEIGHT, width), np.nan)
    for chunk in range(width // _CHUNK + 1):
        rng = _chunk_rng(seed, _BUILDINGS, chunk)
        for _ in range(_BUILDINGS_PER_CHUNK):
            x0 = int(rng.integers(0, _CHUNK)) + chunk * _CHUNK
            span = int(rng.integers(6, 20))
            roof = int(rng.integers(_PAD + 6, _HEIGHT - 10))
            tone = float(rng.uniform(0.15, 0.9))
            if x0 < width:
                structures[roof:, x0 : x0 + span] = tone
                structures[roof : roof + 2, x0 : x0 + span] = tone * 0.5
        rng = _chunk_rng(seed, _POLES, chunk)
        for _ in range(_POLES_PER_CHUNK):
            x0 = int(rng.integers(0, _CHUNK)) + chunk * _CHUNK
            thick = int(rng.integers(1, 3))
            top = int(rng.integers(0, _PAD + 6))
            tone = float(rng.uniform(0.05, 0.2))
            if x0 < width:
                structures[top:, x0 : x0 + thick] = tone
    band = _HEIGHT - _PAD - 5
    structures[band:, :] = 0.55
    structures[band + 1, :] = 0.25
    structures[band + 3, :] = 0.25
    return structures


def _render_traversal(base: _Base, season: Season, n_places: int, seed: int) -> np.ndarray:
    width = base.sky.shape[1]
    blobs = np.zeros_like(base.sky)
    multipliers: dict[int, np.ndarray] = {}
    ys = np.arange(_HEIGHT, dtype=np.float64)
    for cy, cx, sy, sx, amplitude, index in base.blobs:
        chunk = int(cx // _CHUNK)
        if chunk not in multipliers:
            rng = _chunk_rng(seed, _SEASON_STREAM + season.code, chunk)
            multipliers[chunk] = rng.normal(1.0, season.blob_spread, _BLOBS_PER_CHUNK)  # spread 0: exactly 1
        x0, x1 = max(int(cx - 3 * sx), 0), min(int(cx + 3 * sx) + 1, width)
        if x0 >= x1:
            continue
        xs = np.arange(x0, x1, dtype=np.float64)
        bump = np.exp(-0.5 * ((ys[:, None] - cy) / sy) ** 2 - 0.5 * ((xs[None, :] - cx) / sx) ** 2)
        blobs[:, x0:x1] += amplitude * multipliers[chunk][index] * bump
    if season.foliage:
        blobs += _knots_2d(seed, _SEASON_STREAM + 50 + season.code, (3, 3), width, season.foliage)
    terrain = (1.0 - season.snow) * (base.terrain + blobs) + season.snow * 0.85
    panorama = np.where(base.ground, terrain, base.sky)
    panorama = np.where(np.isnan(base.structures), panorama, base.structures)
    panorama = np.clip(season.contrast * (np.clip(panorama, 0.0, 1.0) - 0.5) + 0.5, 0.0, 1.0) ** season.gamma
    panorama = season.gain * panorama + season.offset
    images = np.empty((n_places, IMAGE_HEIGHT, IMAGE_WIDTH), dtype=np.uint8)
    for place in range(n_places):
        rng = np.random.default_rng([seed, _IMAGE_STREAM + season.code, place])
        dy, dx = rng.integers(-season.shift, season.shift + 1, 2) if season.shift else (0, 0)
        top, left = _PAD + int(dy), _PAD + place * STRIDE + int(dx)
        window = panorama[top : top + IMAGE_HEIGHT, left : left + IMAGE_WIDTH]
        if season.noise:
            window = window + rng.normal(0.0, season.noise, window.shape)
        images[place] = np.rint(np.clip(window, 0.0, 1.0) * 255.0).astype(np.uint8)
    return images
