"""An image's width and height read from its header, before any pixel is decoded.

A decoder allocates the whole image before it can say anything about it (a 20000 x 20000 PNG of a few kilobytes
decodes to over a gigabyte), so the memory a decode needs is checked against the limit from the header first
(:func:`vprsnn_export.data.preprocess.decode_checked`). Read here:

* PNG: the IHDR chunk, big-endian width and height at bytes 16 and 20;
* JPEG: the first start-of-frame marker (SOF0-SOF15 but DHT C4, JPG C8, DAC CC), height then width;
* BMP: little-endian signed width and height at bytes 18 and 22 (a negative height is top-down);
* PNM (PBM/PGM/PPM): the ASCII tokens after the magic number, comments skipped;
* WebP: the VP8 / VP8L / VP8X chunk's size fields.

Other formats (TIFF) give None: their size is not known before decoding (OpenCV's ``CV_IO_MAX_IMAGE_PIXELS`` applies).
"""

from __future__ import annotations

import re

_PNG = b"\x89PNG\r\n\x1a\n"
_NO_LENGTH = frozenset({0x01, *range(0xD0, 0xDA)})  # TEM, RSTn, SOI, EOI: markers without a length field
_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
_PNM = re.compile(rb"\AP[1-6](?:\s+|#[^\n]*\n)*?(\d{1,10})(?:\s+|#[^\n]*\n)+?(\d{1,10})\s")


def _be(data: bytes, at: int, size: int) -> int:
    return int.from_bytes(data[at : at + size], "big")


def _le(data: bytes, at: int, size: int, signed: bool = False) -> int:
    return int.from_bytes(data[at : at + size], "little", signed=signed)


def _jpeg(data: bytes) -> tuple[int, int] | None:
    at = 2
    while at + 9 <= len(data):
        if data[at] != 0xFF:
            return None
        marker = data[at + 1]
        if marker == 0xFF:  # fill byte
            at += 1
            continue
        if marker in _NO_LENGTH:
            at += 2
            continue
        if marker in _SOF:
            return _be(data, at + 7, 2), _be(data, at + 5, 2)
        at += 2 + _be(data, at + 2, 2)
    return None


def _webp(data: bytes) -> tuple[int, int] | None:
    chunk = data[12:16]
    if chunk == b"VP8X" and len(data) >= 30:
        return 1 + _le(data, 24, 3), 1 + _le(data, 27, 3)
    if chunk == b"VP8L" and len(data) >= 25:
        bits = _le(data, 21, 4)
        return 1 + (bits & 0x3FFF), 1 + ((bits >> 14) & 0x3FFF)
    if chunk == b"VP8 " and len(data) >= 30:
        return _le(data, 26, 2) & 0x3FFF, _le(data, 28, 2) & 0x3FFF
    return None


def image_dimensions(data: bytes) -> tuple[int, int] | None:
    """(width, height) that the header of the encoded image ``data`` names; None when not known from it."""
    if data.startswith(_PNG) and data[12:16] == b"IHDR" and len(data) >= 24:
        return _be(data, 16, 4), _be(data, 20, 4)
    if data.startswith(b"\xff\xd8"):
        return _jpeg(data)
    if data.startswith(b"BM") and len(data) >= 26:
        return abs(_le(data, 18, 4, signed=True)), abs(_le(data, 22, 4, signed=True))
    if data.startswith(b"RIFF") and data[8:12] == b"WEBP":
        return _webp(data)
    found = _PNM.match(data[:1024])
    return (int(found.group(1)), int(found.group(2))) if found else None
