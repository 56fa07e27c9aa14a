"""Lowcam: make computer graphics look as if a real, cheap camera had filmed them.

An implementation of Klein & Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE TVCG
16(3), 2010 [Klein2010]. The engine never imports Blender.

>>> import lowcam
>>> profile = lowcam.load_profile("fire-i")
>>> [e.name for e in profile.effects][:3]
['lens_distortion', 'half_sampling', 'crosstalk']

Contents
--------
- :func:`simulate`: the camera's 8-bit RGB frame for a premultiplied RGBA render over a plate (sec. 5.2)
- :func:`run`: the same as a :class:`Result`, optionally with every stage's output
- :class:`Result`: one simulated frame, its footprint, stages and final state
- :func:`render_camera`: the camera (pinhole or equidistant fisheye, field of view, sensor fit, resolution) a
  renderer must use
- :func:`render_field_of_view`: pinhole half-extents (X, Y) the render must cover
- :class:`Profile`: a validated camera profile: the frame and its ordered chain of effects
- :func:`load_profile`: load a profile by bundled name (``"fire-i"``) or path
- :func:`list_profiles`: (name, path) of every profile on the search path
- :func:`trust_plugins`: trust plug-in modules, so that profiles may name their effects (``"my_effects:Haze"``)
- :func:`read_render`: a render as premultiplied linear RGBA float32 (H, W, 4)
- :func:`read_plate`: the video frame as uint8, checked against the camera's frame size
- :func:`write_image`: write by extension: ``.exr`` float RGBA, anything else PNG
- :func:`write_png`: write a uint8/uint16 image as PNG, atomically
- :class:`LowcamError`: every user-facing problem, as one line naming the file or key
- :class:`ProfileError`: a profile that does not validate

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from .effects import trust_plugins
from .errors import LowcamError, ProfileError
from .io import read_plate, read_render
from .outputs import write_image, write_png
from .pipeline import Result, render_camera, render_field_of_view, run, simulate
from .profile import Profile, list_profiles, load_profile

__version__ = "0.1.0"

__all__ = ["LowcamError", "ProfileError", "Profile", "Result", "list_profiles", "load_profile", "read_plate",
           "read_render", "render_camera", "render_field_of_view", "run", "simulate", "trust_plugins", "write_image",
           "write_png"]
