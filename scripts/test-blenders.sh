#!/usr/bin/env bash
# The Blender test matrix: the Blender tier (tests/test_blender.py, test_extension.py, test_render_passes.py,
# test_colour_management.py, test_viewport_look.py, marker "blender") under each supported Blender, then a real
# Blender binary. Each part prints its time.
#   bash scripts/test-blenders.sh              every part
#   bash scripts/test-blenders.sh bpy42 bpy45  some parts: bpy42 (bpy 4.2 LTS), bpy45 (4.5 LTS), bpy50 (5.0), trixie
# Further pytest arguments go after "--" (e.g. -- -x -k extension).
# The bpy parts run under Python 3.11, each in its own venv made here on first use (.venv-bpy42, .venv-bpy45;
# bpy 5.0 is the project's own .venv from scripts/setup.sh), at constraints.txt's versions but for bpy, reinstalled
# when pyproject.toml or constraints.txt changes.
set -uo pipefail
cd "$(dirname "$0")/.."

parts=()
while [ $# -gt 0 ] && [ "$1" != "--" ]; do parts+=("$1"); shift; done
[ "${1:-}" = "--" ] && shift
[ ${#parts[@]} -eq 0 ] && parts=(bpy42 bpy45 bpy50 trixie)
TESTS=(tests/test_blender.py tests/test_extension.py tests/test_render_passes.py tests/test_colour_management.py
       tests/test_viewport_look.py tests/test_video.py)
declare -A BPY=([bpy42]="4.2.*" [bpy45]="4.5.*")

python311() {
  for cand in python3.11 python3; do
    if command -v "$cand" >/dev/null 2>&1 && "$cand" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
      echo "$cand"; return 0
    fi
  done
  echo "test-blenders: Python 3.11 is needed (the bpy 4.2-5.0 wheels exist only for it); install it" >&2
  return 1
}

# venv_for PART: the venv of a bpy part, made or refreshed when pyproject.toml or the bpy pin changed.
venv_for() {
  local part=$1
  if [ "$part" = bpy50 ]; then bash scripts/setup.sh >&2 || return 1; echo .venv; return 0; fi
  local dir=.venv-$part spec="bpy==${BPY[$part]}" py
  # as scripts/setup.sh: the ColorChecker detector without its opencv-python requirement
  local detector="colour-checker-detection==0.2.1"
  local want; want="$(cat pyproject.toml constraints.txt | sha256sum | cut -d' ' -f1) $spec $detector"
  if [ ! -f "$dir/.lowcam-installed" ] || [ "$(cat "$dir/.lowcam-installed")" != "$want" ]; then
    py=$(python311) || return 1
    [ -x "$dir/bin/python" ] || "$py" -m venv "$dir" || return 1
    echo "test-blenders: installing $spec and Lowcam into $dir (bpy is large: minutes the first time)" >&2
    grep -v '^bpy==' constraints.txt > "$dir/constraints.txt"  # the locked versions, but this part's bpy
    if ! { "$dir/bin/python" -m pip install --disable-pip-version-check -q -c "$dir/constraints.txt" "$spec" -e . \
             pytest pytest-timeout \
             pillow packaging &&
           "$dir/bin/python" -m pip install --disable-pip-version-check -q --no-deps "$detector"; } \
        >"$dir/pip-install.log" 2>&1; then
      echo "test-blenders: pip install failed; the log is in $dir/pip-install.log" >&2
      return 1
    fi
    echo "$want" > "$dir/.lowcam-installed"
  fi
  echo "$dir"
}

declare -A RESULT
run_part() {
  local part=$1 start=$SECONDS rc venv
  shift
  echo "=== test-blenders: $part ==="
  case $part in
    bpy42|bpy45|bpy50)
      if venv=$(venv_for "$part"); then
        "$venv/bin/python" -c 'import bpy; print("bpy", bpy.app.version_string)'
        # os._exit after pytest: bpy 4.2 can crash (status 139) and 4.5 hang while the interpreter exits
        nice "$venv/bin/python" -c 'import os, sys, pytest; rc = int(pytest.main(sys.argv[1:]));
sys.stdout.flush(); sys.stderr.flush(); os._exit(rc)' -m blender "${TESTS[@]}" -p no:cacheprovider -q -rs "$@"
        rc=$?
      else
        rc=1
      fi ;;
    trixie)
      # --- Real Blender 4.3 binary (Python 3.13) + bpy 5.2 under a Debian trixie root ----------------------
      # (status 77: the root cannot be built here, e.g. not root; counted as skipped)
      bash scripts/trixie-blender.sh "$@"
      rc=$?
      if [ "$rc" = 77 ]; then
        echo "test-blenders: trixie skipped (see the line above)"
        rc=0
      fi ;;
    *) echo "test-blenders: unknown part '$part' (parts: bpy42 bpy45 bpy50 trixie)" >&2; rc=2 ;;
  esac
  RESULT[$part]="$([ "$rc" = 0 ] && echo passed || echo "FAILED (status $rc)") in $((SECONDS - start)) s"
  echo "=== test-blenders: $part ${RESULT[$part]} ==="
  return "$rc"
}

status=0
for part in "${parts[@]}"; do
  run_part "$part" "$@" || status=1
done
echo "=== test-blenders summary ==="
for part in "${parts[@]}"; do echo "  $part: ${RESULT[$part]}"; done
exit "$status"
