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
