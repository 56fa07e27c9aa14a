"""Lowcam: make computer graphics look as if a real, cheap camera had filmed them.

An implementation of Klein & Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE TVCG
16(3), 2010. The engine never imports Blender.

>>> import lowcam
>>> profile = lowcam.load_profile("fire-i")
>>> [e.name for e in profile.effects][:3]
['lens_distortion', 'half_sampling', 'crosstalk']
"""
from .errors import LowcamError, ProfileError
from .io import read_plate, read_render, write_image, write_png
from .pipeline import Result, render_camera, render_field_of_view, run, simulate
from .profile import Profile, list_profiles, load_profile

__version__ = "0.1.0"

__all__ = ["LowcamError", "ProfileError", "Profile", "Result", "list_profiles", "load_profile", "read_plate",
           "read_render", "render_camera", "render_field_of_view", "run", "simulate", "write_image", "write_png"]
