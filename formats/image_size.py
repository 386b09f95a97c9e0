"""The pixel size an image file declares in its header, checked before it is decoded.

A tiny file can declare an enormous image (a "decompression bomb": a 100 kB PNG of
100000 x 100000 pixels would take 30 GB once decoded). :func:`check_image_size` reads the
width and height from the header of a PNG, JPEG, BMP, GIF, WebP or TIFF file and refuses more
than :data:`MAX_IMAGE_PIXELS` pixels with one line naming the file, before OpenCV allocates
anything. Other formats are left to OpenCV's own limit (``CV_IO_MAX_IMAGE_PIXELS``).
"""

from __future__ import annotations

import os
import struct

__all__ = ["MAX_IMAGE_PIXELS", "ImageTooLargeError", "check_image_size", "declared_image_size"]

MAX_IMAGE_PIXELS = 1 << 27
"""Most pixels of one image read (134 million, e.g. 16384 x 8192: 400 MB as BGR)."""

_HEADER_BYTES = 1 << 20  # enough for a JPEG's metadata segments before its frame header
_JPEG_SOF = frozenset({0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD,
                       0xCE, 0xCF})
_JPEG_NO_LENGTH = frozenset({0x01, 0xD8, *range(0xD0, 0xD8)})


class ImageTooLargeError(ValueError):
    """An image whose header declares more pixels than :data:`MAX_IMAGE_PIXELS`."""


def _jpeg_size(data: bytes) -> tuple[int, int] | None:
    i = 2
    while i + 9 <= len(data):
        if data[i] != 0xFF:
            return None
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in _JPEG_SOF:
            height, width = struct.unpack(">HH", data[i + 5 : i + 9])
            return width, height
        if marker in _JPEG_NO_LENGTH:
            i += 2
            continue
        if marker == 0xDA:  # start of scan before any frame header
            return None
        i += 2 + struct.unpack(">H", data[i + 2 : i + 4])[0]
    return None


def _webp_size(data: bytes) -> tuple[int, int] | None:
    chunk = data[12:16]
    if chunk == b"VP8X" and len(data) >= 30:
        return (int.from_bytes(data[24:27], "little") + 1,
                int.from_bytes(data[27:30], "little") + 1)
    if chunk == b"VP8L" and len(data) >= 25:
        bits = int.from_bytes(data[21:25], "little")
        return (bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1
    if chunk == b"VP8 " and len(data) >= 30:
        width, height = struct.unpack("<HH", data[26:30])
        return width & 0x3FFF, height & 0x3FFF
    return None


def _tiff_size(data: bytes) -> tuple[int, int] | None:
    order = "<" if data[:2] == b"II" else ">"
    if len(data) < 8:
        return None
    offset = struct.unpack(order + "I", data[4:8])[0]
    if offset + 2 > len(data):
        return None
    count = struct.unpack(order + "H", data[offset : offset + 2])[0]
    found: dict[int, int] = {}
    for k in range(count):
        start = offset + 2 + 12 * k
        if start + 12 > len(data):
            break
        tag, kind = struct.unpack(order + "HH", data[start : start + 4])
        if tag in (256, 257):
            value = data[start + 8 : start + 12]
            found[tag] = (struct.unpack(order + "H", value[:2])[0] if kind == 3
                          else struct.unpack(order + "I", value)[0])
    if 256 in found and 257 in found:
        return found[256], found[257]
    return None


def declared_image_size(data: bytes) -> tuple[int, int] | None:
    """``(width, height)`` declared by an image file's header; None for an unknown format or a
    header too short or malformed to say."""
    try:
        if data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) >= 24 and data[12:16] == b"IHDR":
            return struct.unpack(">II", data[16:24])
        if data[:2] == b"\xff\xd8":
            return _jpeg_size(data)
        if data[:2] == b"BM" and len(data) >= 26:
            width, height = struct.unpack("<ii", data[18:26])
            return abs(width), abs(height)
        if data[:6] in (b"GIF87a", b"GIF89a") and len(data) >= 10:
            return struct.unpack("<HH", data[6:10])
        if data[:4] == b"RIFF" and data[8:12] == b"WEBP":
            return _webp_size(data)
        if data[:4] in (b"II*\x00", b"MM\x00*"):
            return _tiff_size(data)
    except struct.error:
        return None
    return None


def check_image_size(data: bytes, where: str | os.PathLike,
                     limit: int = MAX_IMAGE_PIXELS) -> None:
    """Refuse an image file whose header declares more than ``limit`` pixels.

    Args:
        data: the file's bytes (bytes or a uint8 array; the first MiB is enough).
        where: the file, named in the message.
        limit: most pixels allowed.

    Raises:
        ImageTooLargeError: one line naming the file and its declared size.
    """
    size = declared_image_size(bytes(data[:_HEADER_BYTES]))
    if size is not None and size[0] * size[1] > limit:
        raise ImageTooLargeError(
            f"{os.fspath(where)}: declares {size[0]}x{size[1]} pixels, more than this xvmatch "
            f"reads ({limit} pixels); a damaged or hostile image?")
