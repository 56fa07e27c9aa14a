#!/usr/bin/env bash
# Set up (first time only) and run the main job on the bundled sample scene.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/lowcam demo "$@"
