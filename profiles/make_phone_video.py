"""Regenerate ``profiles/phone-video.toml``: the phone of ``../shared/data/phone-gyro-video`` (800x600 JPEG video,
gyro log), measured from its own footage without a chart (issue 15, part 3).

The Fire-i chain is set to the clip's camera (its published K, 33.3 ms rolling-shutter read-out, logged exposure:
``lowcam.footage.footage_profile``), then ``lowcam calibrate plate``'s estimates from 24 frames of the footage
(noise, edges and sharpening, vignetting, JPEG quality and chroma subsampling) are applied where confident. Every
number's source is in the profile's ``[provenance]``.

    .venv/bin/python profiles/make_phone_video.py [DATA_DIR] [-o profiles/phone-video.toml]
"""
import argparse
from pathlib import Path

import cv2
import numpy as np

from lowcam.footage import find_footage, footage_profile, read_footage_clip
from lowcam.measure.plate import Footage, estimate_profile
from lowcam.profile import load_profile

HERE = Path(__file__).resolve().parent


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", nargs="?", default=None, help="the phone-gyro-video folder (default: found beside "
                        "the repository)")
    parser.add_argument("-o", "--output", default=str(HERE / "phone-video.toml"))
    args = parser.parse_args()
    data = args.data or HERE.parent.parent / "shared" / "data" / "phone-gyro-video"
    clip = read_footage_clip(find_footage(data), first=99, count=24)
    profile = footage_profile(load_profile("fire-i"), clip)
    profile.camera.name = "Phone video, 800x600 JPEG (gyro-video-stabilization data set)"
    profile.camera.description = "a smartphone's video, measured from its own footage and gyro log, no chart"
    frames = np.stack([cv2.cvtColor(cv2.imread(str(f)), cv2.COLOR_BGR2RGB) for f in clip.frames])
    profile, estimates = estimate_profile(Footage(frames, 30.0, "phone-gyro-video/20200109_145447/reshape"), profile)
    for e in estimates:
        print(e.line())
    # what the plate cannot say keeps the Fire-i's values: say so
    for e in profile.effects:
        if not profile.provenance_of(e.name) and not any(k.startswith(f"{e.name}.") for k in profile.provenance):
            profile.provenance[e.name] = "not measurable from this footage: the Fire-i's (Klein & Murray 2010)"
    print(profile.save(args.output))


if __name__ == "__main__":
    main()
