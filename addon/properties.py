"""Scene settings of the add-on (``scene.lowcam``).

Contents
--------
- :class:`LowcamSettings`: the scene's Lowcam settings (``scene.lowcam``)
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


def _load_profile_defaults(self, context):
    """When the profile changes, show its own sharpness, saturation and exposure."""
    from lowcam.errors import LowcamError
    from lowcam.profile import load_profile

    try:
        controls = load_profile(self.profile).controls()
    except LowcamError:
        return
    for key, value in controls.items():
        setattr(self, key, value)


class LowcamSettings(bpy.types.PropertyGroup):
    enabled: BoolProperty(name="Simulate Camera", default=False,
                          description="Write a degraded composite of every rendered frame (render handler)")
    profile: EnumProperty(name="Profile", items=_profile_items, update=_load_profile_defaults,
                          description="Camera profile (bundled, or in $LOWCAM_PROFILE_PATH)")
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
        ("FILE", "File", "A motion.json or gyro CSV file"),
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
    output: StringProperty(name="Output", subtype="FILE_PATH", default="//lowcam/####.png",
                           options=path_options(),
                           description="Degraded composites; #### is the frame number")


classes = (LowcamSettings,)


def register():
    bpy.types.Scene.lowcam = PointerProperty(type=LowcamSettings)


def unregister():
    del bpy.types.Scene.lowcam
