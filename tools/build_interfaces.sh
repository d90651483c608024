#!/usr/bin/env bash
# Build the project's ROS 2 interface packages into the virtual environment, so that
# `.venv/bin/python -c "import scene_recon_interfaces.srv"` works with nothing sourced.
#
# Idempotent: rebuilds only when an interface file changed (stamp = hash of interfaces/).
# Works around two defects of the ROS 2 PyPI wheels (see shared/REFERENCE.md):
#   * their CMake export files point at /opt/python/cp311-cp311/... include folders of the
#     machine that built them: we rewrite those paths in the venv's own copies (venv-local, no root);
#   * tf2_msgs is not on PyPI: we build a wire-compatible TFMessage-only package when it is absent.
set -euo pipefail
VENV=${VENV:-.venv}
PY="$VENV/bin/python"
BUILD_DIR=${BUILD_DIR:-.build/interfaces}
STAMP="$VENV/.scene_recon_interfaces.stamp"

hash_now=$( (find interfaces -type f -not -name '*.pyc' | sort | xargs sha256sum; sha256sum "$0") | sha256sum | cut -d' ' -f1)
if [ -f "$STAMP" ] && [ "$(cat "$STAMP")" = "$hash_now" ] \
   && "$PY" -c "import scene_recon_interfaces.srv, tf2_msgs.msg" 2>/dev/null; then
  echo "interfaces: up to date"
  exit 0
fi

py_include=$("$PY" -c "import sysconfig; print(sysconfig.get_paths()['include'])")
np_include=$("$PY" -c "import numpy; print(numpy.get_include())")
# Rewrite the wheel-builder paths in the venv's CMake export files (only where still present).
{ grep -rl --include='*.cmake' '/opt/python/cp311-cp311' "$VENV/share" 2>/dev/null || true; } | while read -r f; do
  sed -i \
    -e "s#/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include#${np_include}#g" \
    -e "s#/opt/python/cp311-cp311/include/python3.11#${py_include}#g" "$f"
done

rm -rf "$BUILD_DIR"
mkdir -p "$BUILD_DIR/src"
cp -r interfaces/scene_recon_interfaces "$BUILD_DIR/src/"
if ! "$PY" -c "import tf2_msgs.msg" 2>/dev/null || [ -f "$VENV/share/tf2_msgs/scene_recon_compat" ]; then
  # The compat package carries COLCON_IGNORE so that a colcon build over a stock ROS install
  # never shadows the real tf2_msgs; it is copied without it here.
  cp -r interfaces/compat/tf2_msgs "$BUILD_DIR/src/"
  rm -f "$BUILD_DIR/src/tf2_msgs/COLCON_IGNORE"
  compat=1
else
  compat=0
fi

export AMENT_PREFIX_PATH="$(cd "$VENV" && pwd)"
export CMAKE_PREFIX_PATH="$AMENT_PREFIX_PATH"
export PATH="$AMENT_PREFIX_PATH/bin:$PATH"
export Python3_EXECUTABLE="$AMENT_PREFIX_PATH/bin/python"
(
  cd "$BUILD_DIR"
  "$AMENT_PREFIX_PATH/bin/colcon" --log-base log build --merge-install \
    --install-base "$AMENT_PREFIX_PATH" --build-base build \
    --paths src/* \
    --cmake-args -DPython3_EXECUTABLE="$Python3_EXECUTABLE" -DBUILD_TESTING=OFF \
    >build.log 2>&1 \
    || { tail -40 build.log; echo "interfaces: colcon build failed, full log in $BUILD_DIR/build.log" >&2; exit 1; }
)
[ "$compat" = 1 ] && touch "$VENV/share/tf2_msgs/scene_recon_compat"
"$PY" -c "import scene_recon_interfaces.srv, scene_recon_interfaces.msg, tf2_msgs.msg"
echo "$hash_now" > "$STAMP"
echo "interfaces: built into $VENV (tf2_msgs compat: $compat)"
