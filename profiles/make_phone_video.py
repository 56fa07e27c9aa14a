"""Regenerate ``profiles/phone-video.toml``: the phone of ``../shared/data/phone-gyro-video`` (800x600 JPEG video,
gyro log), measured from its own footage without a chart.

The Fire-i chain is set to the clip's camera (its published K, 33.3 ms rolling-shutter read-out, logged exposure:
``lowcam.gyro_footage.footage_profile``), then ``lowcam calibrate plate``'s estimates from all 103 frames of the
footage (noise, edges and sharpening, vignetting, chroma subsampling) are applied where confident; the JPEG quality,
too high for the plate's blockiness to show, is read from the files' own quantisation tables. Every number's source
is in the profile's ``[provenance]``.

    .venv/bin/python profiles/make_phone_video.py [DATA_DIR] [-o profiles/phone-video.toml]
"""
import argparse
from pathlib import Path

from lowcam.effects.jpeg import ijg_quality
from lowcam.gyro_footage import find_footage, plate_profile, read_footage_clip
from lowcam.profile import load_profile

HERE = Path(__file__).resolve().parent


def file_quality(jpeg_path) -> int:
    """The IJG quality whose scaled standard tables the file's own are (read with Pillow)."""
    from PIL import Image

    tables = Image.open(jpeg_path).quantization
    return ijg_quality(list(tables[0]))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", nargs="?", default=None, help="the phone-gyro-video folder (default: found beside "
                        "the repository)")
    parser.add_argument("-o", "--output", default=str(HERE / "phone-video.toml"))
    args = parser.parse_args()
    data = args.data or HERE.parent.parent / "shared" / "data" / "phone-gyro-video"
    clip = read_footage_clip(find_footage(data), first=99, count=103)
    profile, estimates = plate_profile(load_profile("fire-i"), clip)
    profile.camera.name = "Phone video, 800x600 JPEG (gyro-video-stabilization data set)"
    profile.camera.description = "a smartphone's video, measured from its own footage and gyro log, no chart"
    for e in estimates:
        print(e.line())
    source = "phone-gyro-video/20200109_145447"
    profile.provenance = {k: v.replace(str(clip.folder), source) for k, v in profile.provenance.items()}
    # the phone's chroma is its JPEG's 4:2:0 (the chroma-bandwidth probe), not the Fire-i's 4:1:1 stage
    profile = profile.without("chroma_subsampling")
    profile.provenance["chroma_subsampling"] = "off: the footage's chroma is its JPEG's (chroma bandwidth probe)"
    quality = file_quality(clip.frames[0])  # the plate's blockiness is too weak to read a quality this high
    profile = profile.with_effect("jpeg", quality=quality)
    profile.provenance["jpeg.quality"] = f"the footage's own JPEG quantisation tables (IJG quality {quality})"
    # what the footage did not measure keeps the Fire-i's values: say so
    base = load_profile("fire-i").provenance
    for e in profile.effects:
        if e.name in base and profile.provenance.get(e.name) == base[e.name]:
            profile.provenance[e.name] = f"not measured from this footage; the Fire-i's: {base[e.name]}"
        elif e.name not in profile.provenance:
            profile.provenance[e.name] = "see its parameters"
    print(profile.save(args.output))


if __name__ == "__main__":
    main()
