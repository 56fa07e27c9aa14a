"""Test scenes: exact, analytic renders."""
import numpy as np

from lowcam.pipeline import render_field_of_view


def flat_render(value: float, width: int = 400, height: int = 300, alpha: float = 1.0) -> np.ndarray:
    """A uniform premultiplied render."""
    out = np.empty((height, width, 4), np.float32)
    out[..., :3] = value * alpha
    out[..., 3] = alpha
    return out


def disk_render(profile, radius: float = 0.2, centre=(0.0, 0.0), colour=(1.0, 1.0, 1.0), width: int = 1200):
    """An opaque disk with exact anti-aliased coverage; radius and centre in camera-plane units (tan angles)."""
    half_x, _ = render_field_of_view(profile)
    height = width * profile.camera.height // profile.camera.width
    focal = width / (2 * half_x)
    x = (np.arange(width) - width / 2 + 0.5) / focal
    y = (np.arange(height) - height / 2 + 0.5) / focal
    xx, yy = np.meshgrid(x, y)
    d = np.hypot(xx - centre[0], yy - centre[1])
    alpha = np.clip((radius - d) * focal + 0.5, 0, 1).astype(np.float32)
    out = np.zeros((height, width, 4), np.float32)
    out[..., :3] = alpha[..., None] * np.asarray(colour, np.float32)
    out[..., 3] = alpha
    return out
