"""The arrays the compositor node group needs, computed by the engine's own effect objects (no bpy here).

The node group reproduces :func:`lowcam.pipeline.run` stage by stage on the same grids:

- the supersampled working grid (lens distortion: a Map UV into the render),
- the working grid (half-sampling, crosstalk, spatial blur),
- the sensel mosaic, ``(2 rows, 2 cols)`` of the engine's sensel planes, borders included (Bayer sampling with
  chromatic aberration and motion taps, vignetting, noise, horizontal blur, sharpening, quantisation),
- the output frame (demosaicing, saturation, YUV blending, 4:1:1 chroma).

Everything that depends on the lens, the colour filter array or the camera motion is baked here into images:
Map UV "STMaps" (normalised, origin bottom-left, third component 1), gain maps and convolution kernels. Images
are returned top row first, as numpy holds them; :mod:`nodes.build` flips them for Blender.

Which effects have a node, and how it is built, each effect declares (``Effect.node``,
:class:`lowcam.effects.NodeStage`); the generic recipes (``kernel``, ``gain``, ``matrix``) are baked here from
the effect's own ``kernel()``, ``gain_planes()`` and ``total_matrix()``, so a plug-in effect that declares one
gets a node without changes here. Pure numpy: testable without Blender.

STMaps read pixel (x, y) (top-left origin, centres at integers) at ``u = (x + 0.5) / width``,
``v = 1 - (y + 0.5) / height``, mask 1. In the mosaic, plane (i, j) of a channel with CFA offset (dy, dx) sits
at mosaic pixel (2 i + dy, 2 j + dx); a plane's row filter becomes a mosaic filter with zeros between its taps.

Contents
--------
- :func:`node_stages`: effect name -> :class:`~lowcam.effects.NodeStage` of every effect with a node, in chain order
- :func:`stmap`: a Map UV image that reads pixel (x, y) of a ``width`` x ``height`` image
- :func:`mosaic_shape`: (rows, cols) of the sensel mosaic, borders included
- :func:`planes_to_mosaic`: interleave (4, hb, wb, ...) sensel planes into the (2 hb, 2 wb, ...) mosaic
- :func:`mosaic_kernel`: a row filter over one sensel plane as a (1, 2 taps - 1) filter over the mosaic
- :func:`gaussian_blur_kernel`: the 2-D kernel ``cv2.GaussianBlur(image, (0, 0), sigma)`` uses on float32 images
- :class:`CameraBake`: everything the node group reads, for one profile, render size and camera motion
- :func:`bake`: the images and values of every stage of a profile for a render of ``render_shape`` (rows, cols)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from .effects import known_effects
from .effects.blur import blur_level_maps
from .errors import LowcamError
from .geometry import BAYER_BORDER, CFA_CHANNELS
from .pipeline import run
from .profile import load_profile


def node_stages() -> dict:
    """Effect name -> :class:`~lowcam.effects.NodeStage` of every known effect that has a compositor node, in
    chain order."""
    return {cls.name: cls.node for cls in known_effects() if cls.node is not None}


def stmap(x: np.ndarray, y: np.ndarray, width: int, height: int) -> np.ndarray:
    """An (rows, cols, 4) Map UV image that reads pixel (x, y) (top-left origin, centres at integers) of a
    ``width`` x ``height`` image: ``u = (x + 0.5) / width``, ``v = 1 - (y + 0.5) / height``, mask 1."""
    out = np.ones(np.shape(x) + (4,), np.float32)
    out[..., 0] = (np.asarray(x, np.float64) + 0.5) / width
    out[..., 1] = 1.0 - (np.asarray(y, np.float64) + 0.5) / height
    return out


def mosaic_shape(geometry) -> tuple[int, int]:
    hb, wb = geometry.bayer_shape
    return 2 * hb, 2 * wb


def planes_to_mosaic(planes: np.ndarray, geometry) -> np.ndarray:
    """Interleave (4, hb, wb, ...) sensel planes into the (2 hb, 2 wb, ...) mosaic, borders included: plane
    (i, j) of a channel with CFA offset (dy, dx) sits at mosaic pixel (2 i + dy, 2 j + dx)."""
    hm, wm = mosaic_shape(geometry)
    out = np.zeros((hm, wm) + planes.shape[3:], planes.dtype)
    for k, name in enumerate(CFA_CHANNELS):
        dy, dx = geometry.cfa[name]
        out[dy::2, dx::2] = planes[k]
    return out


def mosaic_kernel(kernel: np.ndarray) -> np.ndarray:
    """A row filter over one sensel plane as a (1, 2 taps - 1) filter over the mosaic (zeros between)."""
    out = np.zeros(2 * len(kernel) - 1, np.float32)
    out[::2] = kernel
    return out[None]


def gaussian_blur_kernel(sigma: float) -> np.ndarray:
    """The 2-D kernel ``cv2.GaussianBlur(image, (0, 0), sigma)`` uses on float32 images."""
    size = int(round(sigma * 8 + 1)) | 1
    k = cv2.getGaussianKernel(size, sigma, cv2.CV_32F)
    return (k @ k.T).astype(np.float32)


@dataclass
class CameraBake:
    """Everything the node group reads, for one profile, render size and camera motion."""

    profile: object
    render_shape: tuple[int, int]
    images: dict = field(default_factory=dict)      # name -> (rows, cols, 4) or (rows, cols) float32, top row first
    values: dict = field(default_factory=dict)      # name -> float or list of floats
    stages: list = field(default_factory=list)      # effect names the group contains, in order

    @property
    def geometry(self):
        return self.profile.geometry


def bake(profile="fire-i", render_shape=(1200, 1600), angular_velocity=(0.0, 0.0, 0.0),
         exposure_s: float | None = None) -> CameraBake:
    """Compute the images and values of every stage of ``profile`` for a render of ``render_shape`` (rows, cols).

    >>> b = bake("fire-i", (600, 800))
    >>> b.images["lens_uv"].shape, b.images["demosaic_uv_R"].shape
    ((1536, 2016, 4), (480, 640, 4))
    """
    profile = load_profile(profile)
    needs_passes = [e.name for e in profile.effects if e.enabled and e.needs_pass]
    if needs_passes:  # object motion, defocus from depth: the render handler's (Blender's Vector Blur, Defocus)
        profile = profile.without(*needs_passes)
    if profile.is_raw:
        raise LowcamError(f"{profile.source}: the compositor node group simulates YUV cameras; "
                          "use the engine (the add-on's render handler) for raw Bayer profiles")
    stages = [e.name for e in profile.effects if e.enabled or e.always_runs]
    declared = node_stages()
    unknown = [s for s in stages if s not in declared]
    if unknown:
        raise LowcamError(f"{profile.source}: the compositor node group has no node for {', '.join(unknown)}; "
                          "use the engine (the add-on's render handler) for this profile")
    demosaic = profile.effect("demosaic")
    if demosaic.method != "block":
        raise LowcamError(f"{profile.source}: the node group demosaics 2x2 blocks only, not {demosaic.method!r}")
    g = profile.geometry
    dummy = np.zeros(tuple(render_shape) + (4,), np.float32)
    before = stages[stages.index("bayer_sampling") - 1]
    state = run(dummy, profile, None, angular_velocity, exposure_s, stop_after=before).state
    out = CameraBake(profile, tuple(render_shape), stages=stages)
    hr, wr = render_shape
    hw, ww = g.working_shape

    # lens distortion: supersampled working grid -> render
    x, y = profile.effect("lens_distortion").render_coordinates(state, tuple(render_shape))
    out.images["lens_uv"] = stmap(x, y, wr, hr)

    # half-sampling: bilinear reads at the corner shared by each 2x2 box are exact box means
    yy, xx = np.mgrid[0:hw, 0:ww].astype(np.float32)
    out.images["half_uv"] = stmap(2 * xx + 0.5, 2 * yy + 0.5, 2 * ww, 2 * hw)
    half = profile.effect("half_sampling")
    e = half.box_enlargement if half.enabled else 0.0
    k = np.array([e, 1 - 2 * e, e], np.float32)
    out.images["half_kernel"] = np.outer(k, k).astype(np.float32)

    if "spatial_blur" in stages:
        blur = profile.effect("spatial_blur")
        sigma_grid = blur.sigma_grid(state) * min(g.working_scale)
        total = np.zeros((hw, ww), np.float32)
        out.values["blur_levels"] = []
        for i, (s, wmap) in enumerate(blur_level_maps(sigma_grid, (hw, ww))):
            total += 1.0 if wmap is None else wmap
            out.values["blur_levels"].append(float(s))
            out.images[f"blur_kernel_{i}"] = gaussian_blur_kernel(s) if s > 0 else np.ones((1, 1), np.float32)
            if i:  # sequential blending as cv2.blendLinear does: acc = acc + t (level - acc), t = w / running sum
                out.images[f"blur_mix_{i}"] = np.divide(wmap, total, out=np.zeros_like(wmap), where=total > 0)

    # Bayer sampling: each mosaic pixel reads its own sensel's position (aberration and motion taps included)
    sx, sy = profile.effect("bayer_sampling").sample_positions(state)     # (4, taps, hb, wb)
    taps = sx.shape[1]
    for t in range(taps):
        mx = planes_to_mosaic(sx[:, t], g)
        my = planes_to_mosaic(sy[:, t], g)
        out.images[f"bayer_uv_{t}"] = stmap(mx, my, ww, hw)
    out.values["bayer_taps"] = taps
    out.values["render_white"] = profile.effect("bayer_sampling").render_white
    out.values["cfa"] = {name: g.cfa[name] for name in CFA_CHANNELS}

    if "noise" in stages:
        noise = profile.effect("noise")
        out.values["noise_law"] = noise.law
        out.values["noise"] = {c: list(getattr(noise, c)) for c in ("red", "green", "blue")}
    if "quantisation" in stages:
        out.values["quantisation_step_dn"] = profile.effect("quantisation").step_dn()

    # 2x2-block demosaicing: output pixel -> the mosaic pixel of its block's sensel (lowcam.effects.bayer)
    by, bx = BAYER_BORDER
    hm, wm = mosaic_shape(g)
    yo, xo = np.mgrid[0:g.height, 0:g.width]
    for name in CFA_CHANNELS:
        dy, dx = g.cfa[name]
        i = (2 * by - dy + yo) // 2
        j = (2 * bx - dx + 1 + xo) // 2
        out.images[f"demosaic_uv_{name}"] = stmap(2 * j + dx, 2 * i + dy, wm, hm)

    if "saturation" in stages:
        s = profile.effect("saturation").total_matrix()
        out.values["saturation_matrix"] = s.ravel().tolist()
        out.values["saturation_inverse"] = np.linalg.pinv(s).ravel().tolist()
    if "chroma_subsampling" in stages:
        n = profile.effect("chroma_subsampling").group
        kernel = np.zeros((1, 2 * n - 1), np.float32)
        kernel[0, n - 1:] = 1.0 / n                       # mean of pixels x .. x + n - 1
        out.images["chroma_kernel"] = kernel
        out.images["chroma_uv"] = stmap(n * (xo // n), yo, g.width, g.height)
    for name in stages:  # the generic recipes, from the effects' own arrays
        effect, builder = profile.effect(name), declared[name].builder
        if builder == "kernel":
            out.images[f"{name}_kernel"] = mosaic_kernel(effect.kernel())
        elif builder == "gain":
            out.images[f"{name}_gain"] = planes_to_mosaic(effect.gain_planes(g), g)
        elif builder == "matrix":
            out.values[f"{name}_matrix"] = effect.total_matrix().ravel().tolist()
    return out
