"""JPEG compression of the delivered frame (a phone's or webcam's MJPEG stream; not in the paper).

The frame is encoded with OpenCV's libjpeg (4:2:0 chroma) and decoded again. The whole frame is recompressed, so
no pixel keeps the plate's exact bytes.

Contents
--------
- :class:`Jpeg`: encodes the final 8-bit frame as JPEG at ``quality`` and decodes it again

References
----------
- [T.81] ITU-T Recommendation T.81 | ISO/IEC 10918-1, "Digital compression and coding of continuous-tone still
  images" (JPEG), 1992.
"""
from __future__ import annotations

import numpy as np

from .base import Effect, Param, Search


class Jpeg(Effect):
    """Encodes the final 8-bit frame as JPEG at ``quality`` and decodes it again (OpenCV's libjpeg, 4:2:0).
    The whole frame is recompressed, so no pixel keeps the plate's exact bytes."""

    name = "jpeg"
    section = "not in the paper"
    writes = "output"
    order = 280
    searches = (Search("jpeg", "8x8 block artefacts as from JPEG quality {quality}",
                       grid={"quality": (30, 50, 70, 80, 90, 95)}, refine={"quality": (-8, -4, 0, 4, 8)}),)
    params = {"quality": Param(90, int, low=1, high=100)}

    def apply(self, state):
        """Nothing before the blend: the encode acts on the delivered frame (:meth:`finish`)."""

    def finish(self, state, frame, footprint):
        import cv2

        from ..errors import LowcamError

        ok, data = cv2.imencode(".jpg", cv2.cvtColor(frame, cv2.COLOR_RGB2BGR),
                                [cv2.IMWRITE_JPEG_QUALITY, int(self.quality)])
        if not ok:
            raise LowcamError(f"{self.source}: JPEG encoding of a {frame.shape[1]}x{frame.shape[0]} frame failed")
        return cv2.cvtColor(cv2.imdecode(data, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB), np.ones_like(footprint)
