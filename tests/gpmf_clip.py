"""A GoPro-style clip made here: a short video (PyAV) with a GPMF metadata track holding a gyro of known angular
velocity, written by hand after GoPro's published format (github.com/gopro/gpmf-parser, README.md: KLV, types,
nesting, ``SCAL``, ``SIUN``, ``STMP``, ``TSMP``; ``GPMF_common.h``: ``ORIN``/``ORIO``) so that telemetry-parser,
Gyroflow's reader, has a file made by something other than Lowcam to read.

GPMF: big-endian KLV triples, a four-character key, a type character, a structure size (bytes), a repeat count
(16 bits), the data padded to 32 bits. A payload is ``DEVC`` (nested) holding ``DVID``, ``DVNM`` and one ``STRM``
(nested) per sensor whose last entry is the data (here ``GYRO``: int16 x3 per sample, divided by ``SCAL``, in the
``SIUN`` unit). FFmpeg's MP4 muxer writes a ``bin_data`` stream as GoPro does: a ``gpmd`` sample entry under a
``meta`` handler named "GoPro MET", one payload per sample.

GoPro's axes ("IMU Orientation Uses These Axis Labels"): X toward the camera's left, Y backward (out of the
screen), Z up, right-handed, rotation positive by the right-hand rule. Lowcam's camera frame is x right, y down,
z forward, so ``X = -x``, ``Y = -z``, ``Z = -y``: :func:`gopro_axes`, written here from GoPro's figure, not from
Lowcam's code.
"""
from __future__ import annotations

import struct
from fractions import Fraction
from pathlib import Path

import numpy as np

#: The data layouts written: ``ORIN`` (the stored columns in GoPro's labels, lower case negated; None: no ORIN,
#: HERO5's documented order Z, X, Y) and ``ORIO`` (``ZXY``, what GoPro's cameras write).
LAYOUTS = {"hero8-style YxZ": "YxZ", "hero5-style ZXY": None}
GYRO_HZ = 200.0       # samples per second (HERO6's rate)
SCAL = 939            # raw units per rad/s (a GoPro MAX's gyro scale)


def klv(key: str, kind: str, size: int, repeat: int, data: bytes) -> bytes:
    """One GPMF KLV: key, type, structure size, repeat, data padded to 32 bits."""
    assert len(key) == 4 and len(data) == size * repeat
    return key.encode() + kind.encode() + struct.pack(">BH", size, repeat) + data + b"\0" * (-len(data) % 4)


def nested(key: str, *items: bytes) -> bytes:
    body = b"".join(items)
    return klv(key, "\0", 1, len(body), body)


def text(key: str, value: str) -> bytes:
    return klv(key, "c", 1, len(value), value.encode())


def gopro_axes(w_camera: np.ndarray) -> np.ndarray:
    """Rates (N, 3) in Lowcam's camera frame (x right, y down, z forward) as GoPro's X (left), Y (back), Z (up)."""
    w = np.asarray(w_camera, np.float64)
    return np.stack([-w[:, 0], -w[:, 2], -w[:, 1]], -1)


def stored_columns(w_gopro: np.ndarray, orin: str | None) -> np.ndarray:
    """GoPro-axis rates as the columns ``orin`` names (``YxZ``: Y, -X, Z); None: HERO5's Z, X, Y."""
    orin = orin or "ZXY"
    cols = []
    for letter in orin:
        v = w_gopro[:, "XYZ".index(letter.upper())]
        cols.append(v if letter.isupper() else -v)
    return np.stack(cols, -1)


def payload(k: int, t0_s: float, w_camera: np.ndarray, orin: str | None, total_before: int) -> bytes:
    """Payload ``k``: its samples' rates (camera frame) as GPMF, stamped ``t0_s`` (``STMP``, us)."""
    raw = np.round(stored_columns(gopro_axes(w_camera), orin) * SCAL)
    assert np.abs(raw).max() < 32767
    items = [klv("STMP", "J", 8, 1, struct.pack(">Q", round(t0_s * 1e6))),
             klv("TSMP", "L", 4, 1, struct.pack(">L", total_before + len(raw))),
             text("STNM", "Gyroscope (z,x,y)")]
    if orin is not None:
        items += [text("ORIN", orin), text("ORIO", "ZXY")]
    items += [text("SIUN", "rad/s"), klv("SCAL", "s", 2, 1, struct.pack(">h", SCAL)),
              klv("GYRO", "s", 6, len(raw), raw.astype(">i2").tobytes())]
    return nested("DEVC", klv("DVID", "L", 4, 1, struct.pack(">L", 1)), text("DVNM", "Camera"),
                  nested("STRM", *items))


def write_gopro_clip(path: Path, rate, seconds: int = 2, fps: int = 30, orin: str | None = "YxZ",
                     gyro: bool = True) -> Path:
    """A ``seconds`` long clip at ``fps`` (64x48 MPEG-4, each frame a different grey) whose GPMF track holds the
    gyro ``rate(t)`` (rad/s, Lowcam's camera frame) at :data:`GYRO_HZ`, sample i at ``i / GYRO_HZ`` s, one payload
    per second; ``gyro`` False: the video alone."""
    import av

    with av.open(str(path), "w", format="mp4") as out:
        video = out.add_stream("mpeg4", rate=fps)
        video.width, video.height, video.pix_fmt = 64, 48, "yuv420p"
        data = out.add_data_stream("bin_data") if gyro else None
        per = int(GYRO_HZ)
        for k in range(seconds if gyro else 0):
            t = (k * per + np.arange(per)) / GYRO_HZ
            packet = av.Packet(payload(k, k, rate(t), orin, k * per))
            packet.stream, packet.time_base = data, Fraction(1, 1000)
            packet.pts = packet.dts = 1000 * k
            packet.duration = 1000
            out.mux(packet)
        for i in range(seconds * fps):
            frame = av.VideoFrame.from_ndarray(np.full((48, 64, 3), (i * 4) % 256, np.uint8), format="rgb24")
            out.mux(video.encode(frame))
        out.mux(video.encode())
    return path
