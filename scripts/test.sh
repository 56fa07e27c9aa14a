#!/usr/bin/env bash
# Set up (first time only) and run the tests.
#   bash scripts/test.sh            the fast tier (minutes): everything not marked slow or blender
#   bash scripts/test.sh --all      every tier: fast, blender (real bpy) and slow (what CI runs)
#   bash scripts/test.sh --tier X   one tier by marker expression, e.g. --tier blender
# Further arguments go to pytest (a file, -k, -x ...).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
tier=(-m "not slow and not blender")
case "${1:-}" in
  --all) tier=(); shift ;;
  --tier) tier=(-m "${2:?--tier needs a marker expression}"); shift 2 ;;
esac
exec .venv/bin/python -m pytest "${tier[@]}" "$@"
