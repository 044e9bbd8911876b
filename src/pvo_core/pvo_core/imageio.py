"""Image decoding for the dataset readers.

PGM/PPM (Devon Island) are decoded here with numpy; PNG (KITTI) through OpenCV's codec, imported
lazily so that the rest of ``pvo_core`` does not need it. Every failure names the file.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .errors import DataFormatError


def _read_netpbm(path: Path) -> NDArray[np.uint8]:
    data = path.read_bytes()
    magic = data[:2]
    if magic not in (b"P5", b"P6"):
        raise DataFormatError(path, f"not a binary PGM/PPM image (magic {magic!r})")
    fields: list[int] = []
    pos = 2
    while len(fields) < 3:
        while pos < len(data) and data[pos : pos + 1].isspace():
            pos += 1
        if data[pos : pos + 1] == b"#":
            while pos < len(data) and data[pos : pos + 1] not in (b"\n", b"\r"):
                pos += 1
            continue
        start = pos
        while pos < len(data) and data[pos : pos + 1].isdigit():
            pos += 1
        if start == pos:
            raise DataFormatError(path, "malformed PGM/PPM header")
        fields.append(int(data[start:pos]))
    pos += 1  # the single whitespace byte after maxval
    width, height, maxval = fields
    if maxval != 255:
        raise DataFormatError(path, f"only 8-bit PGM/PPM is supported (maxval {maxval})")
    channels = 1 if magic == b"P5" else 3
    needed = width * height * channels
    pixels = np.frombuffer(data, dtype=np.uint8, count=min(needed, max(len(data) - pos, 0)), offset=pos)
    if pixels.size != needed:
        raise DataFormatError(path, f"truncated image: {pixels.size} of {needed} pixel bytes")
    shape = (height, width) if channels == 1 else (height, width, 3)
    return pixels.reshape(shape).copy()


def read_image(path: str | Path) -> NDArray[np.uint8]:
    """An 8-bit image: (H, W) grey or (H, W, 3) RGB. Raises DataFormatError naming the file."""
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, "image file not found")
    if path.suffix.lower() in (".pgm", ".ppm"):
        return _read_netpbm(path)
    import cv2  # lazily: only PNG/JPEG need OpenCV's codecs

    buffer = np.fromfile(path, dtype=np.uint8)
    image = cv2.imdecode(buffer, cv2.IMREAD_UNCHANGED) if buffer.size else None
    if image is None:
        raise DataFormatError(path, "unreadable or truncated image")
    if image.dtype != np.uint8:
        raise DataFormatError(path, f"only 8-bit images are supported, got {image.dtype}")
    if image.ndim == 3:
        if image.shape[2] == 4:
            image = image[:, :, :3]
        image = np.ascontiguousarray(image[:, :, ::-1])  # BGR -> RGB
    return image
