"""JPEG compression of the delivered frame (a phone's or webcam's MJPEG stream; not in the paper)."""
from __future__ import annotations

from .base import Effect, Param


class Jpeg(Effect):
    """Encodes the final 8-bit frame as JPEG at ``quality`` and decodes it again (OpenCV's libjpeg, 4:2:0).
    The whole frame is recompressed, so no pixel keeps the plate's exact bytes."""

    name = "jpeg"
    section = "not in the paper"
    writes = "output"
    params = {"quality": Param(90, int, low=1, high=100)}

    def apply(self, state):
        state.jpeg_quality = self.quality
