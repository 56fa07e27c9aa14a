"""Synthetic measurement sets: bundled ideal scenes through a profile with hidden changes (``lowcam synth``).

Contents
--------
- :data:`PAN`: the camera's angular velocity (rad/s) during the "pan" capture
- :func:`scenes`: ideal scenes framed for a profile: name -> (premultiplied RGBA render, angular velocity)
- :func:`parse_change`: ``EFFECT`` or ``EFFECT:key=value,key=value`` -> (effect, {key: value}, the spec)
- :func:`hidden_profile`: a profile with effects added or changed and others switched off
- :func:`synthesise`: write a measurement set made by a profile with hidden changes; returns its folder
"""
from __future__ import annotations

import cv2
import numpy as np

from ..chart import make_chart
from ..errors import LowcamError
from ..outputs import make_output_folder
from ..pipeline import has_temporal, prepare, render_field_of_view, resume_sequence, simulate
from ..sample import photograph
from .sets import write_set

PAN = (0.05, 0.6, 0.1)  # rad/s: the camera turns during the "pan" capture


def _opaque(rgb: np.ndarray) -> np.ndarray:
    out = np.ones(rgb.shape[:2] + (4,), np.float32)
    out[..., :3] = rgb if rgb.ndim == 3 else rgb[..., None]
    return out


def scenes(profile, width: int = 640) -> dict:
    """Ideal scenes framed for ``profile``: name -> (premultiplied RGBA render, angular velocity)."""
    render_field_of_view(profile)  # validates that the profile can be rendered for
    height = width * profile.camera.height // profile.camera.width
    size = (width, height)

    def fit(img):
        img = np.asarray(img, np.float32) / 255.0
        h, w = img.shape[:2]
        if w / h > width / height:
            cw = int(h * width / height)
            img = img[:, (w - cw) // 2:(w - cw) // 2 + cw]
        else:
            ch = int(w * height / width)
            img = img[(h - ch) // 2:(h - ch) // 2 + ch]
        return cv2.resize(img, size, interpolation=cv2.INTER_AREA)

    chart, _ = make_chart("a4", 100)
    rng = np.random.default_rng(3)
    noise = cv2.resize(rng.random((height // 6, width // 6)).astype(np.float32), size,
                       interpolation=cv2.INTER_NEAREST)
    photo = 0.05 + 0.85 * fit(photograph("astronaut"))
    out = {
        "chart": (_opaque(0.05 + 0.85 * fit(chart)), (0.0, 0.0, 0.0)),
        "photo": (_opaque(photo), (0.0, 0.0, 0.0)),
        "noise-field": (_opaque(0.1 + 0.8 * noise), (0.0, 0.0, 0.0)),
        "flat-bright": (_opaque(np.full(size[::-1], 0.7, np.float32)), (0.0, 0.0, 0.0)),
        "flat-dark": (_opaque(np.full(size[::-1], 0.15, np.float32)), (0.0, 0.0, 0.0)),
        "pan": (_opaque(0.05 + 0.85 * fit(photograph("coffee"))), PAN),
    }
    return out


def parse_change(spec: str):
    """``EFFECT`` or ``EFFECT:key=value,key=value`` -> (effect, {key: value}, ``spec``)."""
    name, _, rest = spec.partition(":")
    values = {}
    for item in filter(None, rest.split(",")):
        key, eq, value = item.partition("=")
        if not eq:
            raise LowcamError(f"--add {spec}: use EFFECT:key=value,key=value")
        try:
            values[key.strip()] = int(value) if value.strip().lstrip("-").isdigit() else float(value)
        except ValueError:
            values[key.strip()] = value.strip()
    return name.strip(), values, spec


def hidden_profile(profile, add=(), remove=()):
    """``profile`` with effects added or changed (``add``: (name, values), or :func:`parse_change`'s (name,
    values, spec), whose errors then name the ``--add`` spec) and others switched off."""
    p = profile
    for name, values, *spec in add:
        p = p.with_effect(name, source=f"--add {spec[0]}" if spec else None, **values)
    for name in remove:
        if p.effect(name) is None:
            raise LowcamError(f"--remove {name}: {p.source} has no effect '{name}' (its chain: "
                              f"{', '.join(e.name for e in p.effects)})")
    return p.without(*remove) if remove else p


def synthesise(profile, folder, add=(), remove=(), frames: int = 6, width: int = 640, seed: int = 7,
               only_scenes=None):
    """Write a measurement set made by ``profile`` with hidden changes; returns its folder. ``only_scenes``
    limits it to those of :func:`scenes` (a small, focused set). With an effect that acts across frames (a
    temporal filter, a video encoder) each capture's frames are one sequence
    (:func:`~lowcam.pipeline.resume_sequence`)."""
    camera = hidden_profile(profile, add, remove)
    captures = []
    every = scenes(profile, width)
    unknown = sorted(set(only_scenes or ()) - set(every))
    if unknown:
        raise LowcamError(f"unknown scene '{unknown[0]}' (known: {', '.join(every)})")
    for i, (name, (ideal, omega)) in enumerate(every.items()):
        if only_scenes and name not in only_scenes:
            continue
        # each capture its own noise (a noise repeated across captures would look like a fixed pattern)
        if has_temporal(camera):  # a capture's frames as one sequence (a temporal filter, a video encoder)
            shots = list(resume_sequence(prepare(ideal, camera, None, omega), seed + 1000 * i, frames, camera))
        else:
            shots = [simulate(ideal, camera, None, omega, None, seed + 1000 * i, k) for k in range(frames)]
        captures.append({"name": name, "ideal": ideal, "frames": shots, "angular_velocity": omega})
    return write_set(make_output_folder(folder), captures)
