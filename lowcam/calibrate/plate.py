"""A profile from the footage itself, no chart, no ideal: the plate probes of :mod:`lowcam.measure.plate` run on
the plate's frames, each estimate with its confidence.

Contents
--------
- :func:`calibrate_plate`: a profile from the footage itself, no chart, no ideal (:mod:`lowcam.measure.plate`)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

import sys
from pathlib import Path

import av
import numpy as np

from ..errors import LowcamError
from ..measure import plate
from ..plate_estimate import format_value
from ..reports import figure
from ..video import is_video
from .checks import load_checked
from .outcome import Calibration


def _plate_figures(estimates, plot_dir: Path, base) -> list[Path]:
    """One plot per estimate that has something to draw: the noise level function, the edge profiles, the radial
    fall-off and the gyro's angular velocity, each beside the base profile's model where it was measured."""
    figures = []
    channels = ("red", "green", "blue")
    colours = ("tab:red", "tab:green", "tab:blue")
    for est in estimates:
        m, model = est.measured, est.model or {}
        if est.statistic == "noise_level_function" and m.get("levels_dn"):
            def draw(fig, m=m, model=model, est=est):
                ax = fig.add_subplot(1, 1, 1)
                for ch, col in zip(channels + ("luma",), colours + ("black",)):  # JPEG-coded footage: its luma
                    if ch not in m["levels_dn"]:
                        continue
                    ax.plot(m["levels_dn"][ch], m["sigma_dn"][ch], "o", color=col, ms=4, label=f"footage {ch}")
                    if model.get("levels_dn", {}).get(ch):
                        ax.plot(model["levels_dn"][ch], model["sigma_dn"][ch], "-", color=col, alpha=0.6,
                                label=f"base profile {ch}")
                ax.set_xlabel("mean (DN)")
                ax.set_ylabel("noise sigma (DN, as delivered)")
                ax.set_title(f"noise level function ({m['method']}), confidence {est.confidence:.2f}")
                ax.legend(fontsize=7)
            figures.append(figure(plot_dir / "plate-noise.png", draw))
        elif est.statistic == "edge_profile" and m.get("across_x", {}).get("profile"):
            def draw(fig, m=m, model=model, est=est):
                for k, (key, what) in enumerate((("across_x", "across near-vertical edges (rows)"),
                                                 ("across_y", "across near-horizontal edges (columns)"))):
                    ax = fig.add_subplot(1, 2, k + 1)
                    if m[key].get("profile"):
                        ax.plot(m[key]["offsets_px"], m[key]["profile"], label=f"footage ({m[key]['edges']} edges)")
                    if model.get(key, {}).get("profile"):
                        ax.plot(model[key]["offsets_px"], model[key]["profile"], "--", label="base profile")
                    ax.set_xlabel("px from the edge")
                    ax.set_title(what, fontsize=9)
                    ax.legend(fontsize=7)
            figures.append(figure(plot_dir / "plate-edges.png", draw, (10, 4)))
        elif est.statistic == "radial_falloff" and "c2" in m:
            def draw(fig, m=m, est=est):
                ax = fig.add_subplot(1, 1, 1)
                r = np.linspace(0, 1, 50)
                ax.plot(r, np.exp(m["c2"] * r ** 2 + m["c4"] * r ** 4), label="footage")
                vig = base.effect("vignetting")
                if vig is not None:  # the base's gain texture (or radial model) against radius
                    w, h = base.camera.width, base.camera.height
                    gain = vig.gain_texture(w, h)
                    rows, cols = gain.shape
                    yy, xx = np.mgrid[0:rows, 0:cols]
                    rho = np.hypot((xx + 0.5) * w / cols - w / 2, (yy + 0.5) * h / rows - h / 2) / (np.hypot(w, h) / 2)
                    ax.plot(rho.ravel(), gain.ravel(), ".", ms=1, alpha=0.4, label="base profile")
                ax.set_xlabel("radius / half-diagonal")
                ax.set_ylabel("gain")
                ax.set_title(f"vignetting, confidence {est.confidence:.2f}")
                ax.legend()
            figures.append(figure(plot_dir / "plate-vignetting.png", draw))
        elif est.statistic == "gyro_motion" and m.get("angular_velocity_rad_s"):
            def draw(fig, m=m):
                ax = fig.add_subplot(1, 1, 1)
                w = np.array([v if v is not None else [np.nan] * 3 for v in m["angular_velocity_rad_s"]])
                for k, (axis, col) in enumerate(zip("xyz", colours)):
                    ax.plot(w[:, k], color=col, label=f"w{axis}")
                ax.set_xlabel("frame")
                ax.set_ylabel("rad/s (gyro axes)")
                ax.legend()
            figures.append(figure(plot_dir / "plate-gyro.png", draw))
    return figures


def _ffmpeg_version() -> str:
    major, minor, micro = av.library_versions["libavcodec"]
    return f"libavcodec {major}.{minor}.{micro}"


def calibrate_plate(footage, base, gyro: str | None = None, fps: float | None = None,
                    min_confidence: float | None = None, plot_dir: Path | None = None,
                    progress: bool | None = None, plate_colour: str | None = None) -> Calibration:
    """A profile from the footage itself: :func:`lowcam.measure.plate.estimate_profile` on
    ``footage`` (a video file, a folder of frames, or frame names or patterns), starting from ``base``. Confident
    estimates become the calibration's values, each with a ``[provenance]`` entry; the others are listed, not
    written; footage from which nothing can be estimated is refused (one line with every estimate's reason). With
    ``plot_dir`` the base profile films similar content (:func:`lowcam.measure.plate.model_statistics`) and each
    statistic is plotted beside the model's. ``progress`` (stderr; default: when stderr is a terminal).
    ``plate_colour``: a video's matrix, range and transfer overriding its tags (``--plate-colour``). A video's
    coding as its bitstream states it (codec, profile, GOP structure, frame types, bitrate, the encoder's rate
    control where it wrote it: :func:`lowcam.video.stream_facts`) goes into the profile's ``[video]`` table, with
    its ``[provenance]``."""
    progress = sys.stderr.isatty() if progress is None else progress

    names = [str(f) for f in ([footage] if isinstance(footage, (str, Path)) else footage)]
    if plate_colour and not (len(names) == 1 and is_video(names[0])):
        raise LowcamError(f"--plate-colour {plate_colour}: only a video has colour tags to override "
                          f"({', '.join(names)[:200]} is not one video file)")
    if len(names) == 1 and not any(c in names[0] for c in "*?["):
        shot = plate.read_footage(names[0], fps=fps, gyro=gyro, colour=plate_colour)
    else:
        frames, names_read, source = load_checked(names, plate.MIN_FRAMES, "plate estimation")
        shot = plate.Footage(np.stack(frames), fps or 30.0, source, names=names_read)
        plate.check_footage(shot)
        if gyro:
            shot.gyro, shot.frame_times = plate.read_phone_gyro(gyro)
    threshold = plate.MIN_CONFIDENCE if min_confidence is None else float(min_confidence)
    profile, estimates = plate.estimate_profile(shot, base, progress=progress, min_confidence=threshold)
    if not any(e.applied for e in estimates):
        raise LowcamError(f"{shot.path}: nothing could be estimated from the plate: "
                          + "; ".join(f"{e.statistic}: {'' if e.measurable else 'not measurable, '}{e.reason}"
                                      for e in estimates))
    values: dict[str, dict] = {}
    for est in estimates:
        if est.applied:
            for key, value in est.params.items():
                effect, param = plate._target(est, key)
                values.setdefault(effect, {})[param] = value
    values["camera"] = {"name": profile.camera.name}
    provenance = {k: v for k, v in profile.provenance.items() if base.provenance.get(k) != v}
    if shot.video:
        values["video"] = dict(shot.video)
        provenance["video"] = (f"the bitstream of {shot.path} (FFmpeg {_ffmpeg_version()} through PyAV); colour "
                               f"from {shot.video['colour_from']}")
    figures = []
    if plot_dir:
        if progress:
            print("the base profile filming similar content", file=sys.stderr, flush=True)
        plate.model_statistics(shot, base, estimates)
        figures = _plate_figures(estimates, Path(plot_dir), base)
    numbers = {"video": shot.video} if shot.video else {}
    numbers |= {est.statistic: {"effect": est.effect, "measurable": est.measurable,
                               "confidence": est.confidence if est.measurable else None, "reason": est.reason,
                               "applied": est.applied, "params": est.params, "base_params": est.base_params,
                               "footage": plate.headline(est.measured),
                               "model": None if est.model is None else plate.headline(est.model)}
               for est in estimates}
    applied = [e.statistic for e in estimates if e.applied]
    coded = "" if not shot.video else (f" ({shot.video['codec']} {shot.video['codec_profile']}, "
                                        f"{shot.video['colour']})")
    summary = (f"plate {shot.path}{coded}: {len(shot)} frames {shot.shape[1]}x{shot.shape[0]}; applied "
               f"{', '.join(applied) or 'nothing'}; {len(estimates) - len(applied)} reported only")
    def flat(d, prefix=""):
        out = []
        for k, v in (d or {}).items():
            if isinstance(v, dict):
                out += flat(v, f"{prefix}{k}.")
            else:
                out.append(f"{prefix}{k} = {format_value(v)}")
        return "; ".join(out) if not prefix else out

    table = [{"statistic": e.statistic, "effect": e.effect,
              "confidence": f"{e.confidence:.2f}" if e.measurable else "not measurable", "why": e.reason,
              "footage": flat(plate.headline(e.measured)) or "-",
              "base profile on similar content": "-" if e.model is None else (flat(plate.headline(e.model)) or "-"),
              "estimated": flat(e.params) or "-", "base profile's values": flat(e.base_params) or "-",
              "written": "yes" if e.applied else "no"} for e in estimates]
    return Calibration("plate", summary, values, numbers, figures, provenance=provenance,
                       notes=[e.line() for e in estimates], table=table)
