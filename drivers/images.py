"""16-bit grey images to the 8-bit images the tracker reads, by the bits the data actually uses.

Cameras with 10-, 12- or 14-bit sensors often store their data in 16-bit containers (PNG, mono16
messages). OpenCV's own conversion divides by 256, which leaves 12-bit data nearly black; the data's bit
depth is taken from the first image of a stream and kept, so that brightness stays consistent, until a
later image holds larger values: then it is raised (never lowered), so that a dark first image (a lens
cap, auto-exposure settling) does not clip the rest of the stream to white (`BitDepthScaler`).
"""
from __future__ import annotations

import numpy as np

BIT_DEPTHS = (8, 10, 12, 14, 16)


def _depth_of(peak: int) -> int:
    used = max(int(peak).bit_length(), 8)
    return next(b for b in BIT_DEPTHS if used <= b)


def data_bit_depth(image: np.ndarray) -> int:
    """The smallest of BIT_DEPTHS that holds the image's largest value."""
    return _depth_of(int(image.max()))


def to_8bit(image: np.ndarray, bits: int) -> np.ndarray:
    """A uint16 image holding `bits`-bit data as uint8 (>> bits - 8; larger values clipped)."""
    return np.minimum(image >> (bits - 8), 255).astype(np.uint8)


class BitDepthScaler:
    """One stream's 16-bit images to 8 bits.

    Without a given depth, the first image sets it (`data_bit_depth`) and a later image holding larger
    values raises it: `raises` lists each change as (old bits, new bits, that image's maximum). A depth
    given is kept; the images holding larger values are clipped and counted (`clipped_images`).
    """

    def __init__(self, bits: int | None = None) -> None:
        if bits is not None and bits not in BIT_DEPTHS:
            raise ValueError(f"bit depth must be one of {BIT_DEPTHS}, not {bits}")
        self.bits = bits
        self.fixed = bits is not None
        self.first_peak: int | None = None
        self.raises: list[tuple[int, int, int]] = []
        self.clipped_images = 0

    def convert(self, image: np.ndarray) -> np.ndarray:
        """`image` (uint16) as uint8 by the stream's bit depth, raising it first where needed."""
        peak = int(image.max())
        used = _depth_of(peak)
        if self.first_peak is None:
            self.first_peak = peak
        if self.bits is None:
            self.bits = used
        elif used > self.bits:
            if self.fixed:
                self.clipped_images += 1
            else:
                self.raises.append((self.bits, used, peak))
                self.bits = used
        return to_8bit(image, self.bits)

    def raise_note(self, stream: str, where: str) -> str:
        """What the last raise did, for a report note: `where` names the image."""
        old, new, peak = self.raises[-1]
        return (f"{stream}: {where} holds {new}-bit data (maximum {peak}), more than the {old} bits of the "
                f"images before it: scaled by >> {new - 8} from there (those before by >> {old - 8}, so "
                "they are brighter)")
