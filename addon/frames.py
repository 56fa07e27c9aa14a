"""From a Blender scene to the engine's inputs: render set-up, profile with the scene's settings, plate, motion.

Render set-up (:func:`setup_scene`): a transparent film without dither (the scene's view transform and look stay
the user's: the EXR holds the working space's linear light and names it, and the engine converts it), a
multilayer EXR per frame holding the graphics' view layer and, when a collection is excluded, the
"Lowcam Overlay" view layer that renders only that collection; the Vector pass for object motion and the Z pass
for defocus from depth when those are on, with Cycles' own motion blur off; the scene camera gets the field of view
the engine needs (wider than the real camera's, :func:`lowcam.pipeline.render_camera`): a pinhole one, or for a lens
that sees wider than a pinhole render covers, Cycles' equidistant fisheye (EEVEE has none: refused).

Contents
--------
- :data:`CLIP_LENS_KEYS`: Blender tracking-camera models -> lowcam's BlenderLens models and coefficient names
- :func:`settings`: the scene's Lowcam settings
- :func:`scene_profile`: the chosen profile with the scene's sharpness, saturation, object motion, defocus and clip lens
- :func:`clip_lens`: the Movie Clip's tracking camera as lowcam ``lens_distortion`` values (Blender's own model)
- :data:`ENGINE_NAMES`: Blender's render engines by their identifiers, as the user sees them
- :func:`aim_render_camera`: give Blender camera data the projection and field of view of the render camera
- :func:`setup_render_camera`: give a scene the render camera and film the engine needs
- :func:`setup_scene`: prepare a scene for the render handler; returns the render camera (field of view, size)
- :func:`main_layer`: the view layer that holds the graphics (not the overlay's)
- :func:`plate_file`: the Plate pattern's file for a frame, and whether it is one still image
- :data:`MAX_FRAME`: the last frame Blender plays
- :func:`plate_sequence_image`: the Plate pattern as an image sequence for the compositor's Image node
- :func:`plate`: the plate for a frame as uint8 RGB at the camera's size, or None
- :func:`motion`: the camera's angular velocity over a frame's exposure from the chosen motion source
- :func:`output_path`: where a frame's degraded composite goes
- :func:`write_shot_video`: the scene's composites coded into its Video Output, as the plate clip was coded
- :func:`degrade`: simulate the camera on the frame Blender wrote; returns the composite's path
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import bpy

from lowcam.errors import LowcamError
from lowcam.motion import FrameMotion
from lowcam.scene import OVERLAY_LAYER

from ..blender_compat import set_multilayer_exr
from .properties import profile_ref

#: Blender tracking-camera models -> lowcam's BlenderLens models and their coefficient names.
CLIP_LENS_KEYS = {
    "POLYNOMIAL": ("polynomial", ("k1", "k2", "k3")),
    "DIVISION": ("division", ("division_k1", "division_k2")),
    "NUKE": ("nuke", ("nuke_k1", "nuke_k2")),
    "BROWN": ("brown", ("brown_k1", "brown_k2", "brown_k3", "brown_k4", "brown_p1", "brown_p2")),
}


def settings(scene):
    return scene.lowcam


def scene_profile(scene):
    """The chosen profile with the scene's sharpness, saturation, object motion and defocus from depth and
    (optionally) the clip's lens."""
    from lowcam.profile import load_profile

    s = settings(scene)
    profile = load_profile(profile_ref(s)).with_controls(s.sharpness, s.saturation)
    if s.use_clip_lens:
        if s.plate_clip is None:
            raise LowcamError("Clip Lens is on but no Movie Clip is chosen as the plate")
        profile = profile.with_effect("lens_distortion", replace=True, **clip_lens(s.plate_clip))
    for name, on, values in (("object_motion", s.use_object_motion, {}),
                             ("depth_of_field", s.use_depth_of_field,
                              {"focus_distance_m": s.focus_distance_m, "aperture_mm": s.aperture_mm})):
        if on:
            profile = profile.with_effect(name, **values)
        elif profile.effect(name) is not None:
            profile = profile.without(name)
    return profile


def clip_lens(clip) -> dict:
    """The Movie Clip's tracking camera as lowcam ``lens_distortion`` values (Blender's own model)."""
    cam = clip.tracking.camera
    model, keys = CLIP_LENS_KEYS[cam.distortion_model]
    values = {k: float(getattr(cam, k)) for k in keys}
    return dict(model=model, focal_length=float(cam.focal_length), sensor_width=float(cam.sensor_width),
                principal_point=[float(x) for x in cam.principal_point], pixel_aspect=float(cam.pixel_aspect),
                **values)


#: Blender's render engines by their identifiers, as the user sees them (for the fisheye's refusal).
ENGINE_NAMES = {"BLENDER_EEVEE": "EEVEE", "BLENDER_EEVEE_NEXT": "EEVEE", "BLENDER_WORKBENCH": "Workbench"}


def aim_render_camera(data, cam: dict) -> None:
    """Give Blender camera data ``data`` the projection and field of view of ``cam``
    (:func:`lowcam.pipeline.render_camera`): a perspective camera of horizontal field ``hfov_deg``, or Cycles'
    equidistant fisheye (``PANO``, ``FISHEYE_EQUIDISTANT``) whose ``fisheye_fov`` spans the render's width and
    height; no shift."""
    if cam["projection"] == "fisheye_equidistant":
        data.type = "PANO"
        data.panorama_type = "FISHEYE_EQUIDISTANT"
        data.fisheye_fov = math.radians(cam["hfov_deg"])
    else:
        data.type = "PERSP"
        data.sensor_fit = "HORIZONTAL"
        data.angle = math.radians(cam["hfov_deg"])
    data.shift_x = data.shift_y = 0.0


def setup_render_camera(scene, render_width: int | None = None) -> dict:
    """Give ``scene`` the render the engine and the node group take: the projection, field of view and size of
    :func:`lowcam.pipeline.render_camera` (at ``render_width``, default the scene's width; a fisheye's square)
    and a transparent film without dither; the scene's view transform and look are left alone. Returns the render
    camera. A lens rendered through a fisheye needs Cycles (EEVEE has no panoramic camera): refused otherwise."""
    from lowcam.pipeline import render_camera

    width = render_width or scene.render.resolution_x * scene.render.resolution_percentage // 100
    cam = render_camera(scene_profile(scene), width)
    if cam["projection"] != "pinhole" and scene.render.engine != "CYCLES":
        engine = ENGINE_NAMES.get(scene.render.engine, scene.render.engine)
        raise LowcamError(f"{engine} has no panoramic camera, and this profile's lens sees wider than a pinhole "
                          f"render covers: it renders through Cycles' fisheye ({cam['hfov_deg']:.1f} deg); set the "
                          f"render engine to Cycles")
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = cam["width"], cam["height"], 100
    r.film_transparent = True
    r.dither_intensity = 0.0
    if scene.camera is not None:
        aim_render_camera(scene.camera.data, cam)
    return cam


def setup_scene(scene, render_width: int | None = None) -> dict:
    """Prepare ``scene`` for the render handler (:func:`setup_render_camera`, multilayer EXR output at the
    settings' ``render_depth`` and ``render_codec``, the passes and the overlay view layer); returns the render
    camera (field of view, size)."""
    s = settings(scene)
    cam = setup_render_camera(scene, render_width)
    r = scene.render
    r.use_compositing = False
    r.use_motion_blur = False           # lowcam blurs; Cycles writes no Vector pass with its own motion blur on
    settings_ = r.image_settings
    set_multilayer_exr(settings_)
    settings_.color_depth = s.render_depth         # Blender keeps the Depth and Vector passes 32-bit
    settings_.exr_codec = s.render_codec            # lossless: every choice gives the same composite
    settings_.color_management = "FOLLOW_SCENE"     # the working space's linear light, named in the header
    _setup_overlay_layer(scene, s.exclude_collection)
    layer = scene.view_layers[main_layer(scene)]
    layer.use_pass_vector = s.use_object_motion
    layer.use_pass_z = s.use_depth_of_field
    return cam


def _layer_collections(layer_collection):
    yield layer_collection
    for child in layer_collection.children:
        yield from _layer_collections(child)


def _setup_overlay_layer(scene, excluded):
    overlay = scene.view_layers.get(OVERLAY_LAYER)
    if excluded is None:
        if overlay is not None:
            scene.view_layers.remove(overlay)
        return
    if overlay is None:
        overlay = scene.view_layers.new(OVERLAY_LAYER)
    for layer in scene.view_layers:
        for lc in list(_layer_collections(layer.layer_collection))[1:]:
            is_excluded = lc.collection == excluded
            lc.exclude = (not is_excluded) if layer == overlay else is_excluded
    for layer in scene.view_layers:
        layer.use = True


def main_layer(scene) -> str:
    return next(layer.name for layer in scene.view_layers if layer.name != OVERLAY_LAYER)


def plate_file(scene, frame: int) -> tuple[str, bool]:
    """The Plate pattern's file for ``frame`` (an absolute path), and whether the pattern is one still image behind
    every frame (no frame number in it)."""
    from lowcam.batch import expand_pattern

    pattern = bpy.path.abspath(settings(scene).plate_pattern)
    still = "#" not in pattern and "%" not in pattern
    return (pattern if still else expand_pattern(pattern, frame)), still


#: The last frame Blender plays (``MAXFRAME``): a sequence node that long follows any later end of the scene.
MAX_FRAME = 1048574


def _numbered_by_blender(scene, frame: int) -> bool:
    """Whether Blender, which numbers an image sequence by the last number in a file's name (before its
    extension), takes the Plate pattern's file for ``frame`` for frame ``frame``."""
    numbers = re.findall(r"\d+", Path(plate_file(scene, frame)[0]).stem)
    return bool(numbers) and int(numbers[-1]) == frame


def plate_sequence_image(scene):
    """The scene's Plate pattern as a Blender image for the compositor's Image node: an image sequence whose
    frame N is the pattern's file for frame N (a still image where the pattern has no frame number). Raises
    :class:`LowcamError` where Blender cannot play the pattern: the scene's first frame has no file, or the frame
    number is not the last number in the file's name (Blender numbers a sequence by that)."""
    pattern = settings(scene).plate_pattern
    path, still = plate_file(scene, scene.frame_start)
    if not still and not all(_numbered_by_blender(scene, f) for f in (scene.frame_start, scene.frame_start + 1)):
        raise LowcamError(f"{pattern}: Blender plays an image sequence by the last number in the file's name; "
                          "put the frame number there")
    if not Path(path).is_file():
        raise LowcamError(f"{path}: no such file (the plate for frame {scene.frame_start})")
    image = bpy.data.images.load(path, check_existing=True)
    if pattern.startswith("//") and bpy.data.filepath:
        image.filepath = bpy.path.relpath(path)        # relative as the pattern: the .blend can move with it
    if not still:
        image.source = "SEQUENCE"
    return image


def turned_as_blender_shows(clip, path) -> bool:
    """Whether this Blender shows the movie ``clip`` turned by its display matrix (a phone's upright video), so
    that the plate is read so too: Blender 4.5 and later turn it, 4.2 does not. Told by the clip's own size where
    the turn is a quarter of a clip that is not square, else by the version."""
    from lowcam.video import open_video

    video = open_video(path)
    if video.turns % 2 and video.width != video.height:
        return tuple(clip.size) == (video.width, video.height)
    return bpy.app.version >= (4, 5, 0)


def plate(scene, frame: int, profile):
    """The plate for ``frame`` as uint8 RGB at the camera's size, or None."""
    from lowcam.video import read_video_frame
    from lowcam.io import check_plate, read_plate

    s = settings(scene)
    c = profile.camera
    if s.plate_source == "NONE":
        return None
    if s.plate_source == "SEQUENCE":
        return read_plate(plate_file(scene, frame)[0], c.width, c.height)
    clip = s.plate_clip
    if clip is None:
        raise LowcamError("the plate source is Movie Clip but no clip is chosen")
    path = bpy.path.abspath(clip.filepath)
    index = frame - clip.frame_start + clip.frame_offset
    if clip.source == "MOVIE":
        img = read_video_frame(path, index, turned=turned_as_blender_shows(clip, path))
        return check_plate(img, c.width, c.height, name=f"{path} frame {frame}")
    # an image sequence clip: its file names number the frames from the first file's number
    p = Path(path)
    m = re.search(r"(\d+)(?=\.[^.]+$)", p.name)
    if m is None:
        raise LowcamError(f"{path}: cannot find the frame number in the clip's file name")
    name = p.name[:m.start()] + str(int(m.group(1)) + index).zfill(len(m.group(1))) + p.name[m.end():]
    return read_plate(p.with_name(name), c.width, c.height)


_MOTION_FILE_CACHE: dict = {}


def motion(scene, frame: int, exposure_s: float) -> FrameMotion:
    """The camera's angular velocity over ``frame``'s exposure from the chosen motion source."""
    from lowcam.gyro_logs import read_gyro_log
    from lowcam.motion import gyro_to_motion, read_motion_json

    from .motion import camera_motion

    s = settings(scene)
    if s.motion_source == "NONE" or exposure_s <= 0:
        return FrameMotion((0.0, 0.0, 0.0), exposure_s)
    fps = scene.render.fps / scene.render.fps_base
    if s.motion_source == "CAMERA":
        if scene.camera is None:
            raise LowcamError(f"scene '{scene.name}' has no camera to take the motion from")
        return camera_motion(scene, scene.camera, [frame], exposure_s * fps)[frame]
    first = scene.frame_start
    if s.motion_source == "PLATE_GYRO":   # the plate clip's own gyro: scene frame f shows the clip's frame index
        clip = s.plate_clip if s.plate_source == "CLIP" else None
        if clip is None or clip.source != "MOVIE":
            raise LowcamError("Motion 'Plate Clip's Gyro' needs a Movie Clip of a video file as the plate")
        path, first = bpy.path.abspath(clip.filepath), clip.frame_start - clip.frame_offset
    else:
        path = bpy.path.abspath(s.motion_file)
    is_json = s.motion_source == "FILE" and path.lower().endswith(".json")
    key = (path, Path(path).stat().st_mtime if Path(path).exists() else 0)
    if key not in _MOTION_FILE_CACHE:                   # read once, not once per frame
        _MOTION_FILE_CACHE[key] = read_motion_json(path) if is_json else read_gyro_log(path)
    data = _MOTION_FILE_CACHE[key]
    if is_json:
        if frame not in data:
            raise LowcamError(f"{path}: no entry for frame {frame}")
        return data[frame]
    if s.motion_source == "PLATE_GYRO":
        fps = data.fps or fps                           # the clip's frames are k / (its frame rate) apart
    return gyro_to_motion(data.samples, [frame], fps, exposure_s, first_frame=first, source=path)[frame]


def output_path(scene, frame: int) -> Path:
    from lowcam.batch import expand_pattern

    return Path(expand_pattern(bpy.path.abspath(settings(scene).output), frame))


def write_shot_video(scene) -> str:
    """The scene's composites of every frame (start to end, by its step) coded into its Video Output
    (:func:`lowcam.video.write_shot_video`: as the plate Movie Clip was coded, else H.264 at the scene's frame
    rate); one line saying how. Refused in one line while a frame's composite is missing."""
    from lowcam.video import write_shot_video as code

    s = settings(scene)
    frames = range(scene.frame_start, scene.frame_end + 1, max(scene.frame_step, 1))
    files = [output_path(scene, f) for f in frames]
    missing = [f for f, file in zip(frames, files) if not file.is_file()]
    path = bpy.path.abspath(s.video_output)
    if missing:
        raise LowcamError(f"{path}: not written until every frame is made ({len(missing)} of {len(files)} missing, "
                          f"first frame {missing[0]}); render the animation again")
    clip = s.plate_clip if s.plate_source == "CLIP" else None
    plate = bpy.path.abspath(clip.filepath) if clip is not None and clip.source == "MOVIE" else None
    return code(path, files, scene.render.fps / scene.render.fps_base, plate)


def degrade(scene, render_path, frame: int) -> Path:
    """Simulate the camera on the frame Blender wrote to ``render_path``; returns the composite's path. A profile
    whose frames follow the one before (a temporal filter) follows the composite of ``frame - 1``."""
    from lowcam.scene import degrade_frame

    s = settings(scene)
    profile = scene_profile(scene)
    m = motion(scene, frame, s.exposure_s)
    overlay = OVERLAY_LAYER if s.exclude_collection is not None else None
    return degrade_frame(render_path, output_path(scene, frame), profile, plate(scene, frame, profile),
                         m.angular_velocity, s.exposure_s, s.seed, frame, main_layer(scene), overlay,
                         fps=scene.render.fps / scene.render.fps_base,
                         metres_per_unit=scene.unit_settings.scale_length,
                         previous_path=output_path(scene, frame - 1))
