#!/usr/bin/env bash
# Create .venv (Python 3.11) and install Lowcam with everything the tests need, at the versions in
# constraints.txt (the ones the tests passed with). Idempotent: it reinstalls only when pyproject.toml or
# constraints.txt changed since the last successful install.
#   bash scripts/setup.sh            .venv, the locked versions
#   bash scripts/setup.sh --newest   .venv-newest, the newest versions pyproject.toml allows (no constraints)
set -euo pipefail
cd "$(dirname "$0")/.."
venv=.venv constraints=(-c constraints.txt)
if [ "${1:-}" = "--newest" ]; then
  venv=.venv-newest constraints=()
fi

py=""
for cand in python3.11 python3; do
  if command -v "$cand" >/dev/null 2>&1 && "$cand" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
    py=$cand; break
  fi
done
if [ -z "$py" ]; then
  echo "setup: Python 3.11 is needed (bpy 5.0 exists only for 3.11); install it and rerun" >&2
  exit 1
fi

stamp=$venv/.lowcam-installed
want=$(cat pyproject.toml "${constraints[@]:1}" | sha256sum | cut -d' ' -f1)
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
  exit 0
fi
[ -x "$venv/bin/python" ] || "$py" -m venv "$venv"
echo "setup: installing Lowcam and its dependencies into $venv (bpy is large: the first time takes a few minutes)"
log=$venv/pip-install.log
# colour-checker-detection (ColorChecker targets) asks for opencv-python, whose cv2 would replace the
# opencv-contrib build's: it is installed without its requirements (the others are Lowcam's own)
if ! { "$venv/bin/python" -m pip install --disable-pip-version-check "${constraints[@]}" -e ".[test]" &&
       "$venv/bin/python" -m pip install --disable-pip-version-check --no-deps "colour-checker-detection==0.2.1"; } \
     >"$log" 2>&1; then
  grep -E "ERROR|error:" "$log" | tail -20 >&2
  echo "setup: pip install failed; the whole log is in $log" >&2
  exit 1
fi
echo "$want" > "$stamp"
echo "setup: done"
