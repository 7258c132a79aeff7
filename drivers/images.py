"""16-bit grey images to the 8-bit images the tracker reads, by the bits the data actually uses.

Cameras with 10-, 12- or 14-bit sensors often store their data in 16-bit containers (PNG, mono16
messages). OpenCV's own conversion divides by 256, which leaves 12-bit data nearly black; the data's bit
depth is taken from the first image of a stream (fixed after that, so brightness stays consistent).
"""
from __future__ import annotations

import numpy as np

BIT_DEPTHS = (8, 10, 12, 14, 16)


def data_bit_depth(image: np.ndarray) -> int:
    """The smallest of BIT_DEPTHS that holds the image's largest value."""
    used = max(int(image.max()).bit_length(), 8)
    return next(b for b in BIT_DEPTHS if used <= b)


def to_8bit(image: np.ndarray, bits: int) -> np.ndarray:
    """A uint16 image holding `bits`-bit data as uint8 (>> bits - 8; larger values clipped)."""
    return np.minimum(image >> (bits - 8), 255).astype(np.uint8)
