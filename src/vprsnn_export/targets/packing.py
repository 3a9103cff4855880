"""Bit-packed storage of unsigned low-bit integers: b-bit weights in b bits each.

The layout every deployment file of this project uses (and documents in its own header):

    values v_0, v_1, ..., v_{K-1}   the array in row-major (C) order over its stated shape
    v_k occupies stream bits k b .. k b + b - 1, least significant bit first
    stream bit n is bit (n mod 8) of byte n // 8 (least significant bit first)
    bytes = ceil(K b / 8), the unused high bits of the last byte are zero

so v_k = sum_{i < b} bit(k b + i) 2**i. For b = 8 the stream is the plain uint8 array;
for b = 4 and b = 2 it is ONNX's UINT4 / UINT2 raw layout (first element in the low bits).
"""

from __future__ import annotations

from collections.abc import Sequence
from math import prod
from typing import Any

import numpy as np

from vprsnn_export.errors import InvalidValueError

PACKING = "lsb-first-bitstream"
MAX_BITS = 8


def packed_size(count: int, bits: int) -> int:
    """Bytes of ``count`` values of ``bits`` bits: ceil(count bits / 8)."""
    return (count * bits + 7) // 8


def pack_bits(values: np.ndarray, bits: int) -> np.ndarray:
    """The uint8 stream of ``values`` (any shape, row-major), integers in [0, 2**bits - 1], ``bits`` (1 to 8) bits
    each (a validated model's mantissas)."""
    flat = np.asarray(values).reshape(-1)
    planes = np.unpackbits(flat.astype(np.uint8)[:, None], axis=1, bitorder="little")[:, :bits]
    return np.packbits(planes.reshape(-1), bitorder="little")


def unpack_bits(packed: np.ndarray, bits: int, shape: Sequence[int]) -> np.ndarray:
    """Inverse of :func:`pack_bits`: the values as uint8 of ``shape``; a width outside 1 to 8, a wrong length or a set
    padding bit is a ValueError."""
    if not 1 <= bits <= MAX_BITS:
        raise InvalidValueError(f"packed widths are 1 to {MAX_BITS} bits, got {bits}")
    stream = np.asarray(packed)
    count = prod(shape)
    if stream.dtype != np.uint8 or stream.ndim != 1 or stream.size != packed_size(count, bits):
        raise InvalidValueError(
            f"expected {packed_size(count, bits)} packed uint8 bytes for {count} values of {bits} bits, "
            f"got {stream.size} of {stream.dtype} (shape {stream.shape})"
        )
    plane = np.unpackbits(stream, bitorder="little")
    if plane[count * bits :].any():
        raise InvalidValueError("the padding bits after the last packed value are not zero")
    return np.packbits(plane[: count * bits].reshape(count, bits), axis=1, bitorder="little").reshape(tuple(shape))


def describe_packing(bits: int, shape: Sequence[int], layout: str) -> dict[str, Any]:
    """The header object that documents one packed array (what a reader needs to unpack it)."""
    count = prod(shape)
    return {
        "packing": PACKING,
        "bits": bits,
        "shape": list(shape),
        "layout": layout,
        "count": count,
        "bytes": packed_size(count, bits),
        "rule": (
            "values in row-major order over shape; value k = sum_{i < bits} bit(k*bits + i) * 2**i, "
            "stream bit n = bit (n % 8) of byte n // 8 (least significant first); last byte zero-padded"
        ),
    }
