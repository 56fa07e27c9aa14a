"""The vignetting calibration: a gain texture from flat fields (sec. 4.1).

Contents
--------
- :func:`calibrate_vignetting`: the vignetting texture from flat fields (sec. 4.1)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..captures import refuse_saturated
from ..effects.vignetting import fit_vignetting
from ..errors import LowcamError
from ..reports import figure
from .checks import load_checked, require_finite
from .outcome import Calibration, Texture, _write_gain_png


_MIN_FLAT_DN = 10.0


def calibrate_vignetting(patterns, plot_dir: Path | None = None) -> Calibration:
    frames, names, source = load_checked(patterns, 1, "vignetting calibration")
    refuse_saturated(frames, names)
    level = float(np.percentile(np.mean(frames, axis=(0, 3)), 99))
    if level < _MIN_FLAT_DN:
        raise LowcamError(f"{source}: the flat fields are dark ({level:.1f} DN at the 99th percentile, "
                          f"{_MIN_FLAT_DN:g} needed), so the vignetting cannot be measured; raise the exposure")
    gain = fit_vignetting(frames)
    require_finite(source, "the vignetting", gain_texture=gain)
    corners = float(np.mean([gain[0, 0], gain[0, -1], gain[-1, 0], gain[-1, -1]]))
    figures = []
    if plot_dir:
        def draw(fig):
            ax = fig.add_subplot(1, 2, 1)
            im = ax.imshow(gain, cmap="gray", vmin=0, vmax=1)
            fig.colorbar(im, ax=ax)
            ax.set_title("gain texture (80x60)")
            ax = fig.add_subplot(1, 2, 2)
            yy, xx = np.mgrid[0:gain.shape[0], 0:gain.shape[1]]
            r = np.hypot((xx + 0.5) / gain.shape[1] - 0.5, ((yy + 0.5) / gain.shape[0] - 0.5) * 0.75)
            ax.plot(r.ravel() / r.max(), gain.ravel(), ".", ms=2)
            ax.set_xlabel("radius / corner radius")
            ax.set_ylabel("gain")
            ax.set_title("radial fall-off")
        figures.append(figure(Path(plot_dir) / "vignetting.png", draw, (10, 4)))
    return Calibration("vignetting", f"vignetting: {len(frames)} flat fields, corner gain {corners:.3f}",
                       {"vignetting": {}}, {"corner_gain": corners, "frames": len(frames)}, figures,
                       {"vignetting": Texture("texture", gain, "vignetting.png", _write_gain_png)})


#: The Lucas-Kanade patch (px) that aligns red and blue to green.
