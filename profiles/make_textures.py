"""Regenerate the bundled profiles' textures from the physical models stated in each profile.

    python profiles/make_textures.py

No Fire-i or uEye texture was published with the paper (Fig. 2 shows the Fire-i's vignetting only as a picture),
so these are model-made stand-ins, editable like measured ones. ``lowcam calibrate`` writes measured textures in
the same formats.
"""
from pathlib import Path

import numpy as np

from lowcam.effects.chromatic_aberration import radial_ca_grid, write_ca_grid
from lowcam.effects.vignetting import radial_vignetting
from lowcam.outputs import write_png

HERE = Path(__file__).resolve().parent

TEXTURES = {
    # name: (width, height, vignetting k2, k4, red corner px, blue corner px, cubic)
    "fire-i": (640, 480, -0.30, -0.10, 1.2, 0.5, 1.0),
    "ueye": (752, 480, -0.18, -0.06, 0.5, 0.25, 0.5),
}

if __name__ == "__main__":
    for name, (w, h, k2, k4, red, blue, cubic) in TEXTURES.items():
        gain = radial_vignetting(w, h, k2, k4, shape=(60, 80))
        write_png(HERE / name / "vignetting.png", np.round(gain * 65535).astype(np.uint16))
        write_ca_grid(HERE / name / "chromatic_aberration.csv", radial_ca_grid(w, h, red, blue, cubic=cubic), w, h)
        print(f"{name}: vignetting corner gain {gain[0, 0]:.3f}, CA grid written")
