"""Regenerate profiles/rpi-hq.toml: a phone-class sensor from DNG metadata.

    python profiles/make_rpi_hq.py [-o profiles/rpi-hq.toml]

The sensor is the Raspberry Pi High Quality Camera's Sony IMX477 (1/2.3-inch, 1.55 um pixels: the size class of
a phone's main camera). Its DNG tags are the ones PiDNG 4.0.9 writes for it (``pidng.camdefs.RaspberryPiHqCamera``,
sensor mode 3, 4056x3040, 12 bit): ColorMatrix1/2 and ForwardMatrix1/2 for illuminants A and D65 (the Raspberry Pi
Foundation's tuning "Repro 2_5D no LUT"), AsShotNeutral 0.4 1 0.5, BlackLevel 256, WhiteLevel 4095, CFA BGGR. They
are taken from PiDNG's own camera definition here, not copied.

PiDNG writes no NoiseProfile for this camera and none is published for it, so the script adds a real phone's:
the Google Pixel 4a's (Sony IMX363, 1.4 um pixels), as exiftool printed it for PXL_20220509_032418646.dng in
darktable issue #14805 ("White balance error with DNGs from new Android version", 2023-07-24):
``7.93995059211738e-005 1.74393221641367e-007 4.99071429658215e-005 2.43223553297867e-007 7.93995059211738e-005
1.74393221641367e-007`` (S, O for R, G, B). The profile's provenance says so. The frame, optics and raw read-out
are the bundled ``ueye`` profile's (a raw-Bayer camera, sec. 7 of the paper): ``lowcam profile from-dng`` changes
only the sensor.
"""
import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

#: Google Pixel 4a NoiseProfile (S, O per plane R, G, B): darktable issue #14805, PXL_20220509_032418646.dng.
PIXEL_4A_NOISE_PROFILE = [7.93995059211738e-05, 1.74393221641367e-07, 4.99071429658215e-05, 2.43223553297867e-07,
                          7.93995059211738e-05, 1.74393221641367e-07]
NOISE_SOURCE = ("Google Pixel 4a (Sony IMX363) DNG NoiseProfile, PXL_20220509_032418646.dng as printed by exiftool "
                "in darktable issue #14805 (2023-07-24), standing in for the IMX477's (PiDNG publishes none)")


def write_dng(path: Path) -> Path:
    from pidng.camdefs import RaspberryPiHqCamera
    from pidng.core import CAM2DNG
    from pidng.dng import Tag

    camera = RaspberryPiHqCamera(3)
    camera.tags.set(Tag.NoiseProfile, PIXEL_4A_NOISE_PROFILE)
    width = camera.tags.get(Tag.ImageWidth).rawValue[0]
    height = camera.tags.get(Tag.ImageLength).rawValue[0]
    writer = CAM2DNG(camera)
    writer.options(path=str(path.parent), compress=False)
    # A small dark frame: only the tags matter; pidng packs 12-bit data, so the full frame is written.
    return Path(writer.convert(np.full((height, width), 256, np.uint16), filename=path.stem))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", default=str(ROOT / "profiles" / "rpi-hq.toml"))
    args = parser.parse_args(argv)
    from lowcam.dng import profile_from_dng
    from lowcam.profile import load_profile

    with tempfile.TemporaryDirectory() as work:
        dng = write_dng(Path(work) / "rpi-hq-imx477.dng")
        profile, notes = profile_from_dng(dng, load_profile(ROOT / "profiles" / "ueye.toml"))
    camera = profile.camera.values()
    camera["name"] = "Raspberry Pi HQ Camera (Sony IMX477), sensor from DNG metadata"
    camera["description"] = ("Phone-class 1/2.3-inch sensor: colour, levels and CFA from its DNG tags (PiDNG "
                             "4.0.9), noise from a Pixel 4a's DNG NoiseProfile; frame and optics of the ueye profile")
    profile.camera = type(profile.camera)(profile.source, None, **camera)
    profile.provenance["noise"] = NOISE_SOURCE + "; " + profile.provenance["noise"]
    for key in ("crosstalk", "raw_blend.bits", "camera"):
        profile.provenance[key] = "PiDNG 4.0.9 RaspberryPiHqCamera(3) tags: " + profile.provenance[key]
    path = profile.save(args.output)
    for note in notes:
        print(f"note: {note}")
    print(f"{path}: written")
    return 0


if __name__ == "__main__":
    sys.exit(main())
