#!/usr/bin/env bash
# Set up (first time only) and run the tests.
#   bash scripts/test.sh            the fast tier (minutes): everything not marked slow or blender
#   bash scripts/test.sh --all      every tier: fast, blender (real bpy 5.0; as root the real Blender 4.3 binary and
#                                   bpy 5.2) and slow, then the Blender tier under bpy 4.2 LTS and 4.5 LTS
#                                   (scripts/test-blenders.sh bpy42 bpy45); the slow tier runs beside the others,
#                                   one lane per core, and the first lane free takes it from its other end: what
#                                   CI runs. With pytest arguments: pytest over every tier
#   bash scripts/test.sh --tier X   one tier by marker expression, e.g. --tier blender
#   bash scripts/test.sh --newest   the fast tier against the newest versions pyproject.toml allows (.venv-newest),
#                                   listing where they differ from constraints.txt; with --update-constraints
#                                   after it, a pass writes those versions into constraints.txt
# Further arguments go to pytest (a file, -k, -x ...).
set -euo pipefail
cd "$(dirname "$0")/.."
tier=(-m "not slow and not blender")
if [ "${1:-}" = "--newest" ]; then
  shift
  update=0
  if [ "${1:-}" = "--update-constraints" ]; then update=1; shift; fi
  bash scripts/setup.sh --newest
  frozen=$(.venv-newest/bin/python -m pip freeze --exclude-editable --disable-pip-version-check | grep -v -i '^lowcam')
  echo "=== newest versions that differ from constraints.txt ==="
  diff <(grep -v '^#' constraints.txt | sort -f) <(sort -f <<<"$frozen") | grep '^[<>]' || echo "none"
  .venv-newest/bin/python -m pytest "${tier[@]}" -p no:cacheprovider "$@"
  if [ "$update" = 1 ]; then
    { grep '^#' constraints.txt; sort -f <<<"$frozen"; } > constraints.txt.new && mv constraints.txt.new constraints.txt
    echo "constraints.txt now holds the versions the fast tier passed with"
  fi
  exit 0
fi
bash scripts/setup.sh
case "${1:-}" in
  --all)
    shift
    rc=0
    if [ $# -gt 0 ]; then exec .venv/bin/python -m pytest "$@"; fi
    # Two lanes, one per core. The slow tier's diagnoses (pure engine, one thread mostly) run beside the fast and
    # Blender tiers and the older Blenders; when those are done, that lane takes the slow tier from its other end
    # (each test claims itself in a shared folder: tests/conftest.py). Each lane has its own temporary folder; the
    # slow lane's log follows.
    slow_log=$(mktemp /tmp/lowcam-slow-tier.XXXXXX.log)
    slow_tmp=$(mktemp -d /tmp/lowcam-slow-tier.XXXXXX)
    other_tmp=$(mktemp -d /tmp/lowcam-slow-tier.XXXXXX)
    claims=$(mktemp -d /tmp/lowcam-slow-claims.XXXXXX)
    trap 'rm -rf "$slow_log" "$slow_tmp" "$other_tmp" "$claims"' EXIT
    df -h "$slow_tmp" | awk 'NR == 2 {print "test: " $4 " free for temporary files in " $6}'
    slow=(-m "slow and not blender" -p no:cacheprovider)
    # the slow lane below the other's priority: the Blender tier times Blender's responsiveness
    LOWCAM_SHARED_TIER="$claims" nice -n 5 .venv/bin/python -m pytest "${slow[@]}" --basetemp "$slow_tmp" \
      >"$slow_log" 2>&1 &
    slow_pid=$!
    .venv/bin/python -m pytest -m "not slow or blender" || rc=$?
    bash scripts/test-blenders.sh bpy42 bpy45 || rc=$((rc ? rc : 1))
    echo "=== the slow tier from its other end (its first end runs beside the above) ==="
    LOWCAM_SHARED_TIER="$claims" LOWCAM_SHARED_TIER_REVERSED=1 .venv/bin/python -m pytest "${slow[@]}" \
      --basetemp "$other_tmp" || rc=$((rc ? rc : 1))
    slow_rc=0
    wait "$slow_pid" || slow_rc=$?
    echo "=== the slow tier (run beside the above) ==="
    cat "$slow_log"
    exit $((rc ? rc : slow_rc)) ;;
  --tier) tier=(-m "${2:?--tier needs a marker expression}"); shift 2 ;;
esac
exec .venv/bin/python -m pytest "${tier[@]}" "$@"
