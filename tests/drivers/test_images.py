"""drivers.images: 16-bit images to 8 bits by the bits the data uses, and a stream whose first image is
dark (a lens cap, auto-exposure settling) is not clipped to white afterwards."""
from __future__ import annotations

import numpy as np
import pytest

from drivers.images import BitDepthScaler, data_bit_depth, to_8bit


@pytest.mark.parametrize("peak, bits", [(0, 8), (255, 8), (256, 10), (1023, 10), (1024, 12), (4095, 12),
                                        (4096, 14), (16383, 14), (16384, 16), (65535, 16)])
def test_data_bit_depth_is_the_smallest_that_holds_the_peak(peak: int, bits: int) -> None:
    assert data_bit_depth(np.array([[0, peak]], np.uint16)) == bits


def test_a_dark_first_image_raises_the_depth_instead_of_clipping() -> None:
    dark = np.array([[0, 176]], np.uint16)           # 12-bit data, but the first image is dim
    bright = np.array([[0, 4000]], np.uint16)
    scaler = BitDepthScaler()
    np.testing.assert_array_equal(scaler.convert(dark), [[0, 176]])          # 8 bits: >> 0
    np.testing.assert_array_equal(scaler.convert(bright), [[0, 4000 >> 4]])  # not min(4000, 255)
    assert scaler.bits == 12 and scaler.raises == [(8, 12, 4000)] and scaler.first_peak == 176
    np.testing.assert_array_equal(scaler.convert(dark), [[0, 176 >> 4]])     # never lowered
    assert len(scaler.raises) == 1 and scaler.clipped_images == 0
    assert ">> 4 from there" in scaler.raise_note("cam0", "image 3.png")


def test_a_given_depth_is_kept_and_its_clipped_images_counted() -> None:
    scaler = BitDepthScaler(10)
    out = scaler.convert(np.array([[1023, 4095]], np.uint16))
    np.testing.assert_array_equal(out, to_8bit(np.array([[1023, 4095]], np.uint16), 10))
    assert out[0, 1] == 255 and scaler.bits == 10 and scaler.clipped_images == 1 and not scaler.raises
    with pytest.raises(ValueError, match="bit depth"):
        BitDepthScaler(11)
