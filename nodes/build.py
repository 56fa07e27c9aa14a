"""Build the "Lowcam Camera" compositor node group, one node group per stage, from built-in nodes only.

Python-defined nodes crash Blender's compositor at render time, so every pixel operation here is a built-in node:
Map UV (lens, half-sampling, Bayer sampling with chromatic aberration and motion taps, demosaicing, chroma),
Convolve (half-sampling box, spatial blur levels, horizontal blur, sharpening, 4-pixel chroma boxes), Image
Coordinates with floored modulo (Bayer masks), White Noise driven by the scene frame (sensor noise), and Math
nodes (matrices, quantisation, YUV, blending). The images come from :mod:`lowcam.node_maps`, i.e. from the engine.
Which effects have a node, its label, what its sockets carry and its recipe are the effects' own declarations
(``Effect.node``); this module only knows recipes.

Units inside the group: the working image is the render (premultiplied, linear Rec.709); from Bayer sampling on
values are DN / 255; the group's output is linear light that the Standard view transform turns back into those
codes. In a .blend whose working space is not Linear Rec.709 (Blender 5: Linear Rec.2020, ACEScg), the group turns
its Image and Plate inputs into linear Rec.709 first and its output back into the working space, with the engine's
matrices (:func:`lowcam.render_spaces.to_rec709_matrix`), so its frame is the engine's. The file it is written to
needs the Standard view on an sRGB display, without look: :func:`set_code_view` gives an output its own colour
management so, leaving the scene's view alone.

Sensor noise is Gaussian, by the Box-Muller transform [Box1958] of two White Noise values per sensel and frame.

Contents
--------
- :data:`PREFIX`: the prefix of the node group names ("Lowcam")
- :data:`PLATE_BLEND`: the stage after the effects: the YUV difference added to the plate
- :func:`stage_label`: a stage's node label (the effect's declaration)
- :func:`stage_carries`: what a stage's input sockets carry: "image", "mosaic", "rgb" or "yuv"
- :func:`image_from_array`: a float, non-colour Blender image holding an array, packed into the .blend
- :class:`Tree`: small helpers over a compositor node tree: each returns an output socket
- :data:`GENERIC_BUILDERS`: the generic recipes a :class:`lowcam.effects.NodeStage` may name
- :data:`STAGE_BUILDERS`: the recipes of the stages that have their own
- :func:`stage_builder`: the recipe that builds a stage: (tree, input sockets, bake, image namer) -> output sockets
- :func:`stage_sockets`: (inputs, outputs) of a stage's group as (name, socket type) pairs
- :func:`group_name`: the node group name of a stage
- :func:`build_stage_group`: the node group of one stage (default "Lowcam <Stage>"), its images ``<name>: <what>``
- :func:`group_stages`: the group's stages in order: the profile's, less those baked into others, plus the plate blend
- :func:`build_camera_group`: build "Lowcam Camera" from a bake: Image, Plate, Seed and Noise in; Image out
- :func:`set_code_view`: image output settings that write the group's output as its codes (Standard, no look)
- :func:`set_code_display`: display and view settings that show the group's output as its codes
- :data:`CODE_DISPLAY`: the settings :func:`set_code_display` sets, as (display or view, attribute, value)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
- [Box1958] G. E. P. Box and M. E. Muller, "A Note on the Generation of Random Normal Deviates", The Annals of
  Mathematical Statistics 29(2), 610-611, 1958.
"""
from __future__ import annotations

import bpy
import numpy as np

from lowcam.effects.yuv import RGB_TO_YUV, YUV_TO_RGB
from lowcam.node_maps import CameraBake, node_stages

from ..blender_compat import has_node, node_type, working_space

PREFIX = "Lowcam"
#: The stage after the effects: the YUV difference added to the plate.
PLATE_BLEND = "plate_blend"


def stage_label(stage: str) -> str:
    return "Plate Blend" if stage == PLATE_BLEND else node_stages()[stage].label


def stage_carries(stage: str) -> str:
    """What a stage's input sockets carry: "image" RGBA, "mosaic" (R value, G alpha), "rgb" (+ "Alpha"), "yuv"."""
    return "yuv" if stage == PLATE_BLEND else node_stages()[stage].carries


def image_from_array(name: str, array: np.ndarray) -> bpy.types.Image:
    """A float, non-colour Blender image holding ``array`` ((rows, cols), (rows, cols, 4); top row first),
    packed into the .blend so the group travels as an asset. A 2-D array fills all four channels (so a
    convolution kernel filters alpha too)."""
    a = np.asarray(array, np.float32)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 4, axis=-1)
    h, w = a.shape[:2]
    image = bpy.data.images.get(name)
    if image is not None and tuple(image.size) != (w, h):
        bpy.data.images.remove(image)
        image = None
    if image is None:
        image = bpy.data.images.new(name, w, h, alpha=True, float_buffer=True, is_data=True)
    image.colorspace_settings.is_data = True
    image.pixels.foreach_set(np.ascontiguousarray(a[::-1]).ravel())
    image.pack()
    image.use_fake_user = True
    return image


class Tree:
    """Small helpers over a compositor node tree: each returns an output socket."""

    def __init__(self, tree):
        self.tree = tree
        self.nodes, self.links = tree.nodes, tree.links

    def node(self, kind, **inputs):
        n = self.nodes.new(kind)
        for key, value in inputs.items():
            self.set(n.inputs[key], value)
        return n

    def set(self, socket, value):
        if isinstance(value, bpy.types.NodeSocket):
            self.links.new(value, socket)
        else:
            socket.default_value = value

    def math(self, op, a, b=0.0, c=0.0):
        n = self.nodes.new(node_type("math"))
        n.operation = op
        for socket, value in zip(n.inputs, (a, b, c)):
            self.set(socket, value)
        return n.outputs[0]

    def add(self, *terms):
        out = terms[0]
        for t in terms[1:]:
            out = self.math("ADD", out, t)
        return out

    def lerp(self, a, b, t):
        return self.math("MULTIPLY_ADD", self.math("SUBTRACT", b, a), t, a)

    def separate(self, image):
        n = self.node("CompositorNodeSeparateColor", Image=image)
        return list(n.outputs[:4])

    def combine(self, r, g, b, a=1.0):
        n = self.nodes.new("CompositorNodeCombineColor")
        for socket, value in zip(n.inputs, (r, g, b, a)):
            self.set(socket, value)
        return n.outputs[0]

    def image(self, bpy_image):
        n = self.nodes.new("CompositorNodeImage")
        n.image = bpy_image
        return n.outputs[0]

    def map_uv(self, image, uv_image):
        return self.node("CompositorNodeMapUV", Image=image, UV=self.image(uv_image)).outputs[0]

    def convolve(self, image, kernel_image):
        """``image`` filtered by the kernel in ``kernel_image`` (centred; per channel). Blender 5.0+: a Convolve
        node; before 5.0: one Translate node per non-zero tap, weighted and summed channel by channel."""
        if not has_node("convolve"):
            return self.convolve_taps(image, kernel_image)
        n = self.node("CompositorNodeConvolve", Image=image)
        n.inputs["Kernel Data Type"].default_value = "Color"
        n.inputs["Normalize Kernel"].default_value = False
        self.links.new(self.image(kernel_image), n.inputs[3])
        return n.outputs[0]

    def convolve_taps(self, image, kernel_image):
        """Convolve's sum as Translate taps: ``out(x, y) = sum k[i, j] in(x + j - cx, y - (i - cy))`` (rows of
        ``k`` top first), outside the image zero."""
        w, h = kernel_image.size
        k = np.empty(w * h * 4, np.float32)
        kernel_image.pixels.foreach_get(k)
        k = k.reshape(h, w, 4)[::-1]
        acc = [0.0] * 4
        for i in range(h):
            for j in range(w):
                if not k[i, j].any():
                    continue
                dx, dy = j - w // 2, i - h // 2
                shifted = image
                if dx or dy:
                    shifted = self.node("CompositorNodeTranslate", Image=image, X=float(-dx), Y=float(dy)).outputs[0]
                parts = self.separate(shifted)
                acc = [self.math("MULTIPLY_ADD", parts[c], float(k[i, j, c]), acc[c]) for c in range(4)]
        return self.combine(*acc)

    def matrix(self, m, vector):
        """3x3 ``m`` (row-major list) times the three sockets ``vector``."""
        rows = []
        for r in range(3):
            acc = self.math("MULTIPLY", vector[0], m[3 * r])
            for c in (1, 2):
                acc = self.math("MULTIPLY_ADD", vector[c], m[3 * r + c], acc)
            rows.append(acc)
        return rows


def _new_group(name: str, inputs, outputs):
    group = bpy.data.node_groups.get(name)
    if group is None:
        group = bpy.data.node_groups.new(name, "CompositorNodeTree")
    group.nodes.clear()                 # rebuilt in place, so nodes that use the group keep it
    group.interface.clear()
    for socket_name, kind in inputs:
        group.interface.new_socket(name=socket_name, in_out="INPUT", socket_type=kind)
    for socket_name, kind in outputs:
        group.interface.new_socket(name=socket_name, in_out="OUTPUT", socket_type=kind)
    group.use_fake_user = True
    t = Tree(group)
    t.inp = t.nodes.new("NodeGroupInput")
    t.out = t.nodes.new("NodeGroupOutput")
    return group, t


# --- one function per stage: (tree, input sockets, bake, image namer) -> output sockets ---------------------------

def _lens_distortion(t, s, b, img):
    return {"Image": t.map_uv(s["Image"], img("lens_uv"))}


def _half_sampling(t, s, b, img):
    return {"Image": t.convolve(t.map_uv(s["Image"], img("half_uv")), img("half_kernel"))}


def _matrix(t, s, b, img, stage):
    """Generic recipe: the image's colour times the effect's 3x3 matrix, alpha kept."""
    r, g, bl, a = t.separate(s["Image"])
    return {"Image": t.combine(*t.matrix(b.values[f"{stage}_matrix"], (r, g, bl)), a)}


def _spatial_blur(t, s, b, img):
    out = None
    for i, _ in enumerate(b.values["blur_levels"]):
        level = t.convolve(s["Image"], img(f"blur_kernel_{i}"))
        if out is None:
            out = level
            continue
        mix = t.separate(t.image(img(f"blur_mix_{i}")))[0]
        ca, cb = t.separate(out), t.separate(level)
        out = t.combine(*(t.lerp(x, y, mix) for x, y in zip(ca, cb)))
    return {"Image": out}


def _baked_masks(t, b, img):
    """Blender 4.2-4.4 (no Image Coordinates node): the red, green and blue sensel masks baked as one image of the
    mosaic's size (that of the Bayer sampling maps), rows top first."""
    rows, cols = b.images["bayer_uv_0"].shape[:2]
    r, c = np.mgrid[:rows, :cols] % 2
    planes = np.zeros((rows, cols, 4), np.float32)
    for name, (dy, dx) in b.values["cfa"].items():
        planes[..., "RGB".index(name[0])] += (r == dy) & (c == dx)
    planes[..., 3] = 1.0
    image = img.baked("bayer_masks", planes)
    return dict(zip("RGB", t.separate(t.image(image))[:3]))


def _bayer_masks(t, mosaic, b, img):
    """Per-pixel masks of the red, green and blue sensels of the mosaic (Image Coordinates, floored modulo 2)."""
    cfa = b.values["cfa"]
    if not has_node("image_coordinates"):
        return _baked_masks(t, b, img)
    coords = t.node(node_type("image_coordinates"), Image=mosaic).outputs["Pixel"]
    xyz = t.node(node_type("separate_xyz"), Vector=coords).outputs
    col = t.math("FLOORED_MODULO", t.math("FLOOR", xyz[0]), 2.0)
    row_from_bottom = t.math("FLOORED_MODULO", t.math("FLOOR", xyz[1]), 2.0)
    row = t.math("SUBTRACT", 1.0, row_from_bottom)     # the mosaic has an even number of rows
    masks = {"R": 0.0, "G": 0.0, "B": 0.0}
    for name, (dy, dx) in cfa.items():
        on = t.math("MULTIPLY", t.math("COMPARE", col, float(dx), 0.25), t.math("COMPARE", row, float(dy), 0.25))
        key = name[0]
        masks[key] = on if isinstance(masks[key], float) else t.math("ADD", masks[key], on)
    return masks


def _bayer_sampling(t, s, b, img):
    taps = [t.map_uv(s["Image"], img(f"bayer_uv_{i}")) for i in range(b.values["bayer_taps"])]
    sums = [t.separate(x) for x in taps]
    channels = [t.add(*(c[k] for c in sums)) for k in range(4)]
    scale = 1.0 / (len(taps) * b.values["render_white"])
    m = _bayer_masks(t, taps[0], b, img)
    value = t.add(*(t.math("MULTIPLY", channels[k], m[key]) for k, key in enumerate("RGB")))
    return {"Image": t.combine(t.math("MULTIPLY", value, scale), t.math("MULTIPLY", channels[3], 1.0 / len(taps)),
                               0.0, 1.0)}


def _gain(t, s, b, img, stage):
    """Generic recipe: the mosaic's colour times the effect's baked gain map."""
    v, a, _, _ = t.separate(s["Image"])
    gain = t.separate(t.image(img(f"{stage}_gain")))[0]
    return {"Image": t.combine(t.math("MULTIPLY", v, gain), a, 0.0, 1.0)}


def _uniform_pair(t, s, b, img):
    """Two uniform values per sensel, new each frame and seed: White Noise of (pixel, frame + 1000 seed); before
    Blender 4.5 (no White Noise or Image Coordinates in the compositor) a baked uniform image of the mosaic's size
    (fixed seed 0), shifted with wrap-around by a whole number of pixels that depends on frame and seed."""
    frame = t.nodes.new("CompositorNodeSceneTime").outputs["Frame"]
    w = t.math("MULTIPLY_ADD", s["Seed"], 1000.0, frame)
    if has_node("white_noise") and has_node("image_coordinates"):
        coords = t.node(node_type("image_coordinates"), Image=s["Image"]).outputs["Pixel"]
        white = t.nodes.new(node_type("white_noise"))
        white.noise_dimensions = "4D"
        t.set(white.inputs["Vector"], coords)
        t.set(white.inputs["W"], w)
        return white.outputs["Value"], t.separate(white.outputs["Color"])[0]
    rows, cols = b.images["bayer_uv_0"].shape[:2]
    uniform = np.random.default_rng(0).random((rows, cols, 4), dtype=np.float32)
    shift = t.node("CompositorNodeTranslate", Image=t.image(img.baked("uniform", uniform)),
                   X=t.math("FLOOR", t.math("MODULO", t.math("MULTIPLY", w, 61.0), float(cols))),
                   Y=t.math("FLOOR", t.math("MODULO", t.math("MULTIPLY", w, 127.0), float(rows))))
    shift.wrap_axis = "BOTH"
    return t.separate(shift.outputs[0])[:2]


def _noise(t, s, b, img):
    """Gaussian noise per sensel by Box-Muller from two uniform values per sensel and frame (:func:`_uniform_pair`)."""
    v, a, _, _ = t.separate(s["Image"])
    u1, u2 = _uniform_pair(t, s, b, img)
    u1 = t.math("MAXIMUM", u1, 1e-7)
    z = t.math("MULTIPLY", t.math("SQRT", t.math("MULTIPLY", t.math("LOGARITHM", u1, np.e), -2.0)),
               t.math("COSINE", t.math("MULTIPLY", u2, 2 * np.pi)))
    m = _bayer_masks(t, s["Image"], b, img)
    coeff = b.values["noise"]
    pick = lambda i: t.add(*(t.math("MULTIPLY", m[k], coeff[c][i])  # noqa: E731
                             for k, c in zip("RGB", ("red", "green", "blue"))))
    mean_dn = t.math("MINIMUM", t.math("MAXIMUM", t.math("MULTIPLY", t.math("DIVIDE", v, t.math("MAXIMUM", a, 1e-6)),
                                                                      255.0), 0.0), 255.0)
    law = t.math("MAXIMUM", t.math("MULTIPLY_ADD", pick(1), mean_dn, pick(0)), 0.0)  # a < 0: a black level
    sigma_dn = law if b.values["noise_law"] == "sigma_linear" else t.math("SQRT", law)
    alpha = t.math("MINIMUM", t.math("MAXIMUM", a, 0.0), 1.0)
    noise = t.math("MULTIPLY", t.math("MULTIPLY", z, alpha), t.math("DIVIDE", sigma_dn, 255.0))
    return {"Image": t.combine(t.math("MULTIPLY_ADD", noise, s["Strength"], v), a, 0.0, 1.0)}


def _kernel(t, s, b, img, stage):
    """Generic recipe: the mosaic convolved with the effect's baked row kernel."""
    return {"Image": t.convolve(s["Image"], img(f"{stage}_kernel"))}


def _quantisation(t, s, b, img):
    v, a, _, _ = t.separate(s["Image"])
    step = b.values["quantisation_step_dn"] / 255.0
    clipped = t.math("MINIMUM", t.math("MAXIMUM", v, -1.0), 2.0)
    q = t.math("MULTIPLY", t.math("ROUND", t.math("DIVIDE", clipped, step)), step)
    return {"Image": t.combine(q, a, 0.0, 1.0)}


def _demosaic(t, s, b, img):
    picked = {name: t.separate(t.map_uv(s["Image"], img(f"demosaic_uv_{name}"))) for name in ("R", "Gr", "Gb", "B")}
    green = [t.math("MULTIPLY", t.math("ADD", picked["Gr"][i], picked["Gb"][i]), 0.5) for i in (0, 1)]
    return {"Image": t.combine(picked["R"][0], green[0], picked["B"][0], 1.0),
            "Alpha": t.combine(picked["R"][1], green[1], picked["B"][1], 1.0)}


def _saturation(t, s, b, img):
    rgb = t.separate(s["Image"])[:3]
    return {"Image": t.combine(*t.matrix(b.values["saturation_matrix"], rgb), 1.0), "Alpha": s["Alpha"]}


def _linear_to_code(t, x):
    """sRGB encoding (what Blender's Standard view applies to the plate), rounded to 8-bit codes (as DN / 255)."""
    lo = t.math("MULTIPLY", x, 12.92)
    hi = t.math("SUBTRACT", t.math("MULTIPLY", t.math("POWER", t.math("MAXIMUM", x, 0.0), 1 / 2.4), 1.055), 0.055)
    c = t.lerp(hi, lo, t.math("LESS_THAN", x, 0.0031308))
    return t.math("DIVIDE", t.math("ROUND", t.math("MULTIPLY", c, 255.0)), 255.0)


def _code_to_linear(t, c):
    lo = t.math("DIVIDE", c, 12.92)
    hi = t.math("POWER", t.math("DIVIDE", t.math("ADD", c, 0.055), 1.055), 2.4)
    return t.lerp(hi, lo, t.math("LESS_THAN", c, 0.04045))


def _yuv_blend(t, s, b, img):
    """``delta = rgb - S (alpha * S^+ plate)`` in YUV (lowcam.effects.yuv.YuvBlend)."""
    plate = [_linear_to_code(t, x) for x in t.separate(s["Plate"])[:3]]
    rgb = t.separate(s["Image"])[:3]
    alpha = t.separate(s["Alpha"])[:3]
    if "saturation_inverse" in b.values:
        plate = t.matrix(b.values["saturation_inverse"], plate)
    covered = [t.math("MULTIPLY", a, p) for a, p in zip(alpha, plate)]
    if "saturation_matrix" in b.values:
        covered = t.matrix(b.values["saturation_matrix"], covered)
    delta = [t.math("SUBTRACT", x, c) for x, c in zip(rgb, covered)]
    return {"Image": t.combine(*t.matrix(RGB_TO_YUV.ravel().tolist(), delta), 1.0)}


def _chroma_subsampling(t, s, b, img):
    y = t.separate(s["Image"])[0]
    boxed = t.separate(t.map_uv(t.convolve(s["Image"], img("chroma_kernel")), img("chroma_uv")))
    return {"Image": t.combine(y, boxed[1], boxed[2], 1.0)}


def _plate_blend(t, s, b, img):
    """``frame = plate + YUV^-1 delta``, rounded to 8-bit codes and returned as linear light."""
    plate = [_linear_to_code(t, x) for x in t.separate(s["Plate"])[:3]]
    delta = t.matrix(YUV_TO_RGB.ravel().tolist(), t.separate(s["Image"])[:3])
    out = []
    for p, d in zip(plate, delta):
        c = t.math("MINIMUM", t.math("MAXIMUM", t.math("ADD", p, d), 0.0), 1.0)
        out.append(_code_to_linear(t, t.math("DIVIDE", t.math("ROUND", t.math("MULTIPLY", c, 255.0)), 255.0)))
    return {"Image": t.combine(*out, 1.0)}


#: Recipes a :class:`lowcam.effects.NodeStage` may name: generic ones take the stage's name.
GENERIC_BUILDERS = {"kernel": _kernel, "gain": _gain, "matrix": _matrix}
STAGE_BUILDERS = {
    "lens_distortion": _lens_distortion, "half_sampling": _half_sampling, "spatial_blur": _spatial_blur,
    "bayer_sampling": _bayer_sampling, "noise": _noise, "quantisation": _quantisation, "demosaic": _demosaic,
    "saturation": _saturation, "yuv_blend": _yuv_blend, "chroma_subsampling": _chroma_subsampling,
    PLATE_BLEND: _plate_blend,
}


def stage_builder(stage: str):
    """The recipe that builds ``stage``: (tree, input sockets, bake, image namer) -> output sockets."""
    kind = PLATE_BLEND if stage == PLATE_BLEND else node_stages()[stage].builder
    if kind in GENERIC_BUILDERS:
        return lambda t, s, b, img: GENERIC_BUILDERS[kind](t, s, b, img, stage)
    return STAGE_BUILDERS[kind]


def stage_sockets(stage: str):
    """(inputs, outputs) of a stage's group as (name, socket type) pairs."""
    colour = "NodeSocketColor"
    inputs = [("Image", colour)]
    if stage_carries(stage) == "rgb":
        inputs.append(("Alpha", colour))
    if stage in ("yuv_blend", PLATE_BLEND):
        inputs.append(("Plate", colour))
    if stage == "noise":
        inputs += [("Seed", "NodeSocketFloat"), ("Strength", "NodeSocketFloat")]
    outputs = [("Image", colour)] + ([("Alpha", colour)] if stage in ("demosaic", "saturation") else [])
    return inputs, outputs


def group_name(stage: str) -> str:
    return f"{PREFIX} {stage_label(stage)}"


def build_stage_group(stage: str, camera: CameraBake, name: str | None = None):
    """The node group of one stage (named ``name``, default "Lowcam <Stage>"), its images ``<name>: <what>``."""
    inputs, outputs = stage_sockets(stage)
    name = name or group_name(stage)
    group, t = _new_group(name, inputs, outputs)
    if stage == "noise":
        group.interface.items_tree["Strength"].default_value = 1.0
    images = {}

    def img(key):
        if key not in images:
            images[key] = image_from_array(f"{name}: {key}", camera.images[key])
        return images[key]

    def baked(key, array):              # a map the engine does not bake (4.x stand-ins for missing nodes)
        if key not in images:
            images[key] = image_from_array(f"{name}: {key}", array)
        return images[key]

    img.baked = baked

    s = {name: t.inp.outputs[name] for name, _ in inputs}
    result = stage_builder(stage)(t, s, camera, img)
    for name, _ in outputs:
        t.links.new(result[name], t.out.inputs[name])
    return group


def group_stages(camera: CameraBake) -> list[str]:
    """The stages of the group in order: the profile's, less those baked into another's maps, plus the plate
    blend."""
    declared = node_stages()
    return [s for s in camera.stages if not declared[s].baked_into] + [PLATE_BLEND]


def _working_to_rec709():
    """The working space's RGB -> linear Rec.709 matrix (3x3), None when the working space is linear Rec.709."""
    from lowcam.render_spaces import LINEAR_REC709, render_space, to_rec709_matrix

    space = render_space(working_space())
    return None if space == LINEAR_REC709 else to_rec709_matrix(space)


def _convert(t, image, m):
    """``image``'s colour times the 3x3 matrix ``m``, alpha kept."""
    parts = t.separate(image)
    return t.combine(*t.matrix(np.asarray(m, float).ravel().tolist(), parts[:3]), parts[3])


def set_code_view(image_settings) -> None:
    """Image output settings (a render's or a File Output node's) that write the group's output as its 8-bit
    codes whatever the scene's view: their own colour management, the Standard view without look, exposure 0,
    gamma 1, no curves. The scene's view transform and look stay the user's."""
    image_settings.color_management = "OVERRIDE"
    set_code_display(image_settings.display_settings, image_settings.view_settings)


#: The display under which the group's output shows as its 8-bit codes: ("display" or "view" settings, attribute,
#: value), the view transform before its look (a look belongs to a view transform).
CODE_DISPLAY = (("display", "display_device", "sRGB"), ("view", "view_transform", "Standard"),
                ("view", "look", "None"), ("view", "exposure", 0.0), ("view", "gamma", 1.0),
                ("view", "use_curve_mapping", False), ("view", "use_white_balance", False))


def set_code_display(display_settings, view_settings) -> None:
    """Display and view settings under which the group's output shows as its 8-bit codes (:data:`CODE_DISPLAY`):
    an sRGB display, the Standard view without look, exposure 0, gamma 1, no curves, no white balance."""
    settings = {"display": display_settings, "view": view_settings}
    for part, name, value in CODE_DISPLAY:
        if hasattr(settings[part], name):   # white balance: 4.5+
            setattr(settings[part], name, value)


def build_camera_group(camera: CameraBake, name: str = "Lowcam Camera", until: str | None = None):
    """Build "Lowcam Camera" from a :func:`lowcam.node_maps.bake`: inputs Image (the render, premultiplied), Plate,
    Seed, Noise; output Image.

    ``until`` ends the chain after that stage (its raw output goes to the group's output), for parity checks.
    Returns the group; its stage groups are ``group["lowcam_stages"]``.
    """
    stages = group_stages(camera)
    if until is not None:
        stages = stages[:stages.index(until) + 1]
    group, t = _new_group(name, [("Image", "NodeSocketColor"), ("Plate", "NodeSocketColor"),
                                 ("Seed", "NodeSocketFloat"), ("Noise", "NodeSocketFloat")],
                          [("Image", "NodeSocketColor")])
    group.interface.items_tree["Noise"].default_value = 1.0
    to_rec709 = _working_to_rec709()
    inputs = {"Image": t.inp.outputs["Image"], "Plate": t.inp.outputs["Plate"]}
    if to_rec709 is not None:                   # the engine's colour works in linear Rec.709
        inputs = {k: _convert(t, v, to_rec709) for k, v in inputs.items()}
    current = {"Image": inputs["Image"]}
    for i, stage in enumerate(stages):
        node = t.nodes.new("CompositorNodeGroup")
        node.node_tree = build_stage_group(stage, camera, f"{name}: {stage_label(stage)}")
        node.location = (200 * (i + 1), 0)
        for name, _ in stage_sockets(stage)[0]:
            source = {"Plate": inputs["Plate"], "Seed": t.inp.outputs["Seed"],
                      "Strength": t.inp.outputs["Noise"]}.get(name, current.get(name))
            t.links.new(source, node.inputs[name])
        current = {name: node.outputs[name] for name, _ in stage_sockets(stage)[1]}
    out = current["Image"] if to_rec709 is None else _convert(t, current["Image"], np.linalg.inv(to_rec709))
    t.links.new(out, t.out.inputs["Image"])
    t.out.location = (200 * (len(stages) + 1), 0)
    group["lowcam_stages"] = stages
    group["lowcam_profile"] = str(camera.profile.source)
    return group
