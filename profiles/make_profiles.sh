#!/bin/sh
# Regenerates the bundled profiles made by Lowcam's own commands from outside data, so their numbers are
# reproducible. Run from the repository root: sh profiles/make_profiles.sh (needs pip install -e '.[lensfun]').
set -e
cd "$(dirname "$0")/.."
PY="${PYTHON:-python}"

# A phone-class small lens from the lensfun database (lensfun 0.3.4 as lensfunpy bundles it): the iPhone XS
# wide camera's distortion (ptlens), lateral colour (TCA poly3) and vignetting (pa, f/1.8) on the Fire-i's
# 640x480 sensor and pipeline; every other number is fire-i's (the provenance says so).
"$PY" -m lowcam.cli profile from-lensfun --maker Apple --model "iPhone XS back camera 4.25mm f/1.8 & compatibles" \
    --focal-mm 4.25 --aperture 1.8 --distance-m 1000 --base profiles/fire-i.toml \
    --name "Apple iPhone XS wide lens (lensfun) on the Fire-i sensor" -o profiles/iphone-xs-lens.toml

# 16:9 HD cameras of today: a phone (Apple iPhone 12, main "Wide" camera, 1920x1080) and an action camera (GoPro
# HERO8 Black, Wide, 1080p, no stabilisation; Gyroflow's own calibration), each lens a Gyroflow calibration from the
# community database (gyroflow/lens_profiles, CC0; the copy in ../shared/data) with its read-out time and frame rate,
# on the sensor and processing of phone-video (measured from a phone's own footage and gyro log; what was not
# measured there is the Fire-i's, and its provenance says so).
DB="${GYROFLOW_DATABASE:-../shared/data/gyroflow-lens-profiles/lens_profiles.tar.xz}"
PHONE="lens_profiles/Mobile phones/Apple/Apple_iPhone12_raw_cam_Wide_16x9.json"
ACTION="lens_profiles/GoPro/GoPro_HERO8 Black_Wide_NO-EIS_1080p_16by9-200fps.json"
TMP="$(mktemp -d)"
trap 'rm -rf "$TMP"' EXIT
tar -xJf "$DB" -C "$TMP" "$PHONE" "$ACTION"
"$PY" -m lowcam.cli profile from-gyroflow "$TMP/$PHONE" --base profiles/phone-video.toml -o profiles/iphone-12-hd.toml
"$PY" -m lowcam.cli profile from-gyroflow "$TMP/$ACTION" --base profiles/phone-video.toml -o profiles/gopro-hero8-hd.toml
