"""Scene settings of the add-on (``scene.lowcam``).

Contents
--------
- :func:`profile_ref`: the profile the settings choose: the Profile File when one is given, else the menu's name
- :func:`follow_profile`: rebuild the compositor's camera nodes that follow the scene's profile
- :class:`LowcamSettings`: the scene's Lowcam settings (``scene.lowcam``); ``profile_ref()`` as above
- :data:`classes`: the property classes, for registration
- :func:`register`: add ``scene.lowcam`` to every scene
- :func:`unregister`: remove it
"""

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

from ..blender_compat import path_options


def _profile_items(self, context):
    from lowcam.profile import list_profiles

    items = [(name, name, str(path)) for name, path in list_profiles()]
    return items or [("fire-i", "fire-i", "bundled")]


def profile_ref(settings) -> str:
    """The profile ``settings`` (``scene.lowcam``) choose, as ``load_profile`` takes it: the Profile File (a .toml
    anywhere, made absolute) when one is given, else the Profile menu's name (bundled or on the search path)."""
    return bpy.path.abspath(settings.profile_file) if settings.profile_file else settings.profile


def follow_profile(scene) -> None:
    """Rebuild the "Lowcam Camera" nodes of ``scene``'s compositor that follow the scene's profile."""
    from ..blender_compat import compositor_tree

    tree = compositor_tree(scene, create=False)
    for node in getattr(tree, "nodes", ()):
        if getattr(node, "use_scene_profile", False):
            node.on_profile(bpy.context)


def _load_profile_defaults(self, context):
    """When the profile changes, show its own sharpness, saturation and exposure; the camera nodes that follow
    the scene rebuild."""
    from lowcam.errors import LowcamError
    from lowcam.profile import load_profile

    try:
        controls = load_profile(profile_ref(self)).controls()
    except LowcamError:
        return
    for key, value in controls.items():
        setattr(self, key, value)
    scene = self.id_data
    if isinstance(scene, bpy.types.Scene):
        follow_profile(scene)


def _menu_profile(self, context):
    """A name picked from the menu replaces the Profile File."""
    if self.profile_file:
        self.profile_file = ""     # its update loads the defaults
    else:
        _load_profile_defaults(self, context)


class LowcamSettings(bpy.types.PropertyGroup):
    enabled: BoolProperty(name="Simulate Camera", default=False,
                          description="Write a degraded composite of every rendered frame (render handler)")
    profile: EnumProperty(name="Profile", items=_profile_items, update=_menu_profile,
                          description="Camera profile (bundled, or in $LOWCAM_PROFILE_PATH)")
    profile_file: StringProperty(name="Profile File", subtype="FILE_PATH", options=path_options(),
                                 update=_load_profile_defaults,
                                 description="A profile .toml anywhere; when given, it is used instead of the "
                                             "Profile menu's name")
    sharpness: FloatProperty(name="Sharpness", default=80.0, min=0.0, max=255.0,
                             description="The camera's sharpness setting (sec. 4.4.3)")
    saturation: FloatProperty(name="Saturation", default=90.0, min=0.0, max=255.0,
                              description="The camera's saturation setting; 65 is the identity (sec. 4.4.2)")
    exposure_s: FloatProperty(name="Exposure (s)", default=0.033, min=0.0, max=10.0, precision=4,
                              description="Exposure time in seconds: the length of the motion blur")
    seed: IntProperty(name="Seed", default=0, min=0, description="Noise seed; each frame's noise depends on "
                      "(seed, frame) only")
    exclude_collection: PointerProperty(
        name="Excluded", type=bpy.types.Collection,
        description="Objects the camera does not degrade (UI overlays, crosshairs): rendered in their own view "
                    "layer and laid over the composite through the lens geometry only")
    plate_source: EnumProperty(name="Plate", items=[
        ("NONE", "None", "Black background"),
        ("CLIP", "Movie Clip", "The video frames of a Movie Clip"),
        ("SEQUENCE", "Image Sequence", "Files named by a pattern with #### for the frame number")],
        default="NONE")
    plate_clip: PointerProperty(name="Clip", type=bpy.types.MovieClip)
    plate_pattern: StringProperty(name="Pattern", subtype="FILE_PATH", default="//plates/####.png",
                                 options=path_options())
    motion_source: EnumProperty(name="Motion", items=[
        ("CAMERA", "Scene Camera", "Angular velocity of the scene camera (e.g. the solved camera) over the shutter"),
        ("FILE", "File", "A motion.json, a gyro CSV, a Gyroflow .gcsv log or .gyroflow project, or a video clip "
                         "that records its own gyro (GoPro, Sony, Insta360, DJI)"),
        ("PLATE_GYRO", "Plate Clip's Gyro", "The gyro the plate's Movie Clip records in its own file (GoPro, Sony, "
                                            "Insta360, DJI), timed by the clip's frames"),
        ("NONE", "None", "No camera motion blur")], default="CAMERA")
    motion_file: StringProperty(name="Motion File", subtype="FILE_PATH", options=path_options())
    use_object_motion: BoolProperty(
        name="Object Motion", default=True,
        description="Blur what moves relative to the camera's rotation (objects, camera translation) over the "
                    "shutter, from the Vector pass (Cycles' own motion blur is turned off)")
    use_depth_of_field: BoolProperty(name="Defocus from Depth", default=False,
                                     description="Blur each point by its distance from the focus plane (Z pass)")
    focus_distance_m: FloatProperty(name="Focus Distance (m)", default=2.0, min=0.01, max=1e4,
                                    description="Distance of the sharp plane from the camera, in metres")
    aperture_mm: FloatProperty(name="Aperture (mm)", default=1.0, min=0.0, max=200.0,
                               description="Entrance pupil diameter: focal length / f-number (a 2.1 mm f/2 "
                                           "webcam lens: about 1 mm)")
    use_clip_lens: BoolProperty(name="Clip Lens", default=False,
                                description="Use the Movie Clip's tracking camera lens model instead of the profile's")
    render_depth: EnumProperty(name="Render Depth", items=[
        ("32", "Float (32-bit)", "Renders written as Cycles or EEVEE computes them"),
        ("16", "Half Float (16-bit)", "Renders in about a sixth of the disk and read faster; the composites differ "
                                      "slightly from a 32-bit render's (docs/blender.md). Depth and Vector passes "
                                      "stay 32-bit")],
        default="32", description="How the renders the camera degrades are written (OpenEXR)")
    render_codec: EnumProperty(name="Render Compression", items=[
        # the lossless OpenEXR compressions Blender writes: each gives the same composite (docs/benchmarks.md)
        ("NONE", "None", "Uncompressed: the fastest for Blender to write and for Lowcam to read, the largest files"),
        ("ZIP", "ZIP", "Lossless: the smallest files, slower to write and to read"),
        ("PIZ", "PIZ", "Lossless wavelet compression"),
        ("RLE", "RLE", "Lossless run-length compression"),
        ("ZIPS", "ZIPS", "Lossless: ZIP one scanline at a time")],
        default="NONE", description="How Blender compresses the renders the camera degrades (OpenEXR, lossless: "
                                    "every choice gives the same composite)")
    output: StringProperty(name="Output", subtype="FILE_PATH", default="//lowcam/####.png",
                           options=path_options(),
                           description="Degraded composites; #### is the frame number")
    video_output: StringProperty(
        name="Video Output", subtype="FILE_PATH", default="", options=path_options(),
        description="Also code the composites into this video (.mp4, .mov, .mkv) once an animation render has made "
                    "every frame: as the plate Movie Clip was coded (codec, GOP, B-frames, colour tags), else H.264. "
                    "Empty: image files only")

    def profile_ref(self) -> str:
        """:func:`profile_ref` of these settings (the compositor's camera node asks the scene's settings so, without
        importing the add-on: ``nodes/`` stands below ``addon/``)."""
        return profile_ref(self)


classes = (LowcamSettings,)


def register():
    bpy.types.Scene.lowcam = PointerProperty(type=LowcamSettings)


def unregister():
    del bpy.types.Scene.lowcam
