#!/usr/bin/env bash
# A real Blender binary with Python 3.13: Debian trixie's `blender` (4.3) in a chroot built with mmdebstrap.
#   bash scripts/trixie-blender.sh             set up (first time only), then run tests/test_blender_binary.py
#   bash scripts/trixie-blender.sh --setup     only build the root and its bpy 5.2 venv (idempotent)
#   bash scripts/trixie-blender.sh --run CMD   run CMD inside the root (proc mounted), e.g. --run blender -b --version
# Further arguments after the default form go to pytest (-k, -x ...).
#
# The root lives in .cache/trixie-root (ignored by git, about 2 GB with the bpy 5.2 venv) and is built once:
# `mmdebstrap --variant=apt --include=blender,python3-numpy,python3-venv,xvfb,xauth trixie ROOT` (about 40 s to
# 2 min), then a venv /opt/bpy52 inside it with the bpy 5.2 wheel (cp313 only) and Lowcam's runtime imports.
# Building needs root (mmdebstrap's root mode and chroot); without it the script says so and exits 77 (skipped).
# LOWCAM_TRIXIE_ROOT overrides the root's location.
set -euo pipefail
cd "$(dirname "$0")/.."
REPO=$(pwd)
ROOT=${LOWCAM_TRIXIE_ROOT:-$REPO/.cache/trixie-root}
# libegl1 + Mesa: bpy 5.2's compositor opens an EGL context even on the CPU (it aborts without libEGL.so.1)
# imagemagick: `import -window root` grabs the Xvfb screen for the UI screenshots (Blender's own screenshot operator
# reads a black front buffer under Xvfb)
PACKAGES=blender,python3-numpy,python3-venv,xvfb,xauth,libegl1,libegl-mesa0,libgl1-mesa-dri,imagemagick
BPY_SPEC='bpy==5.2.*'
# Lowcam's runtime imports for Python 3.13 (pyproject.toml pins Python 3.11 for the bpy 5.0 tier, so the project
# itself is put on PYTHONPATH rather than pip-installed here).
# OpenCV as the extension bundles it (pyproject.toml: <4.12); numpy is whatever bpy 5.2 takes (2.x).
# PyAV as pyproject.toml pins it (video plates); telemetry-parser has no wheel for Python 3.13 (a clip's own gyro
# is refused there in one line).
RUNTIME_DEPS=("opencv-contrib-python-headless>=4.8,<4.12" "OpenEXR>=3.3" scipy scikit-image matplotlib tomli-w tqdm
  tifffile rapidfuzz "colour-science>=0.4.4,<0.5" "av>=18.1,<19" pytest)

skip() { echo "trixie-blender: skipped: $*" >&2; exit 77; }

if [ "$(id -u)" != 0 ]; then
  skip "needs root (mmdebstrap root mode, chroot, mount proc); run it as root, e.g. sudo bash $0"
fi

ensure_mmdebstrap() {
  command -v mmdebstrap >/dev/null && return
  command -v apt-get >/dev/null || skip "mmdebstrap is missing and there is no apt-get to install it"
  echo "trixie-blender: installing mmdebstrap with apt-get" >&2
  apt-get install -y -q mmdebstrap >/dev/null 2>&1 || { apt-get update -q >/dev/null 2>&1 &&
    apt-get install -y -q mmdebstrap >/dev/null; } || skip "apt-get install mmdebstrap failed"
}

MOUNTED=()
unmount_all() {
  local i
  for ((i = ${#MOUNTED[@]} - 1; i >= 0; i--)); do
    umount "${MOUNTED[i]}" 2>/dev/null || umount -l "${MOUNTED[i]}" || true
  done
  MOUNTED=()
}
trap unmount_all EXIT INT TERM

mount_root() {
  # proc (and a tmpfs /dev/shm) for the chroot; unmounted on exit by the trap, left alone when already mounted.
  if ! mountpoint -q "$ROOT/proc"; then mount -t proc proc "$ROOT/proc"; MOUNTED+=("$ROOT/proc"); fi
  mkdir -p "$ROOT/dev/shm"
  if ! mountpoint -q "$ROOT/dev/shm"; then
    mount -t tmpfs -o size=512m shm "$ROOT/dev/shm" && MOUNTED+=("$ROOT/dev/shm")
  fi
}

remove_tree() {
  # a half-built root may still hold mounts (mmdebstrap mounts proc, sys and dev while it installs): unmount
  # everything below it first, and never cross into another file system while deleting
  [ -e "$1" ] || return 0
  local m
  for m in $(awk -v p="$(realpath "$1")/" 'index($2, p) == 1 {print $2}' /proc/mounts | sort -r); do
    umount "$m" 2>/dev/null || umount -l "$m"
  done
  rm -rf --one-file-system "$1"
}

build_root() {
  if [ -x "$ROOT/usr/bin/blender" ] && [ -f "$ROOT/.lowcam-root-ok" ]; then
    [ "$(cat "$ROOT/.lowcam-root-ok")" = "$PACKAGES" ] && return
    # a root from an older package list: add what is missing
    echo "trixie-blender: installing $PACKAGES in the existing root" >&2
    cp -L /etc/resolv.conf "$ROOT/etc/resolv.conf" 2>/dev/null || true
    mount_root
    chroot "$ROOT" /usr/bin/env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin DEBIAN_FRONTEND=noninteractive \
      sh -c "apt-get update -q >/dev/null && apt-get install -y -q ${PACKAGES//,/ } >/dev/null" \
      || skip "apt-get in the trixie root failed"
    echo "$PACKAGES" > "$ROOT/.lowcam-root-ok"
    return
  fi
  ensure_mmdebstrap
  remove_tree "$ROOT.part"
  mkdir -p "$(dirname "$ROOT")"
  local t0=$SECONDS
  echo "trixie-blender: building the trixie root in $ROOT (once; about 1.3 GB)" >&2
  mmdebstrap --quiet --variant=apt --include="$PACKAGES" trixie "$ROOT.part" \
    || skip "mmdebstrap could not build the trixie root (is deb.debian.org reachable?)"
  remove_tree "$ROOT" && mv "$ROOT.part" "$ROOT"
  echo "$PACKAGES" > "$ROOT/.lowcam-root-ok"
  echo "trixie-blender: root built in $((SECONDS - t0)) s" >&2
}

build_venv() {
  local want="$BPY_SPEC ${RUNTIME_DEPS[*]}"
  if [ -f "$ROOT/opt/bpy52/.lowcam-venv-ok" ] && [ "$(cat "$ROOT/opt/bpy52/.lowcam-venv-ok")" = "$want" ]; then
    return
  fi
  local t0=$SECONDS
  echo "trixie-blender: making /opt/bpy52 in the root (python3.13 venv with $BPY_SPEC, about 400 MB)" >&2
  cp -L /etc/resolv.conf "$ROOT/etc/resolv.conf" 2>/dev/null || true
  # the host's pip trust store goes with it (a host behind a TLS-inspecting proxy trusts the proxy's CA)
  local cert=() host_ca=${PIP_CERT:-${REQUESTS_CA_BUNDLE:-${SSL_CERT_FILE:-}}}
  if [ -n "$host_ca" ] && [ -f "$host_ca" ]; then
    cp -L "$host_ca" "$ROOT/etc/ssl/host-ca-bundle.crt" && cert=(PIP_CERT=/etc/ssl/host-ca-bundle.crt)
  fi
  chroot "$ROOT" python3 -m venv --clear /opt/bpy52
  chroot "$ROOT" /usr/bin/env -i HOME=/root PATH=/usr/bin:/bin "${cert[@]}" \
    /opt/bpy52/bin/pip install -q --disable-pip-version-check "$BPY_SPEC" "${RUNTIME_DEPS[@]}" \
    || skip "pip could not install $BPY_SPEC into the root's python3.13 venv (is pypi.org reachable?)"
  echo "$want" > "$ROOT/opt/bpy52/.lowcam-venv-ok"
  echo "trixie-blender: bpy 5.2 venv made in $((SECONDS - t0)) s" >&2
}

build_root
mount_root
build_venv

case "${1:-}" in
  --setup) chroot "$ROOT" blender -b --factory-startup --version 2>/dev/null | head -1; exit 0 ;;
  --run) shift; set +e; chroot "$ROOT" /usr/bin/env -i HOME=/root LANG=C.UTF-8 PATH=/usr/local/bin:/usr/bin:/bin "$@"
    exit $? ;;
esac
PY=${PYTHON:-}
if [ -z "$PY" ]; then
  if [ -x .venv/bin/python ]; then PY=.venv/bin/python; else bash scripts/setup.sh && PY=.venv/bin/python; fi
fi
export LOWCAM_TRIXIE_ROOT=$ROOT
set +e
"$PY" -m pytest -m blender tests/test_blender_binary.py "$@"
rc=$?
exit $rc
