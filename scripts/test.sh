#!/usr/bin/env bash
# Set up (first time only) and run the tests.
#   bash scripts/test.sh            the fast tier (minutes): everything not marked slow or blender
#   bash scripts/test.sh --all      every tier: fast, blender (real bpy 5.0; as root the real Blender 4.3 binary and
#                                   bpy 5.2) and slow, then the Blender tier under bpy 4.2 LTS and 4.5 LTS
#                                   (scripts/test-blenders.sh bpy42 bpy45; not when pytest arguments follow): what
#                                   CI runs
#   bash scripts/test.sh --tier X   one tier by marker expression, e.g. --tier blender
# Further arguments go to pytest (a file, -k, -x ...).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
tier=(-m "not slow and not blender")
case "${1:-}" in
  --all)
    shift
    rc=0
    .venv/bin/python -m pytest "$@" || rc=$?
    if [ $# -eq 0 ]; then bash scripts/test-blenders.sh bpy42 bpy45 || rc=$((rc ? rc : 1)); fi
    exit "$rc" ;;
  --tier) tier=(-m "${2:?--tier needs a marker expression}"); shift 2 ;;
esac
exec .venv/bin/python -m pytest "${tier[@]}" "$@"
