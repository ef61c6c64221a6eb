# Source this file from bash to use the project's environment in a shell:
#   source scripts/env.sh
# It activates .venv, points ament at it, sources the colcon install space and puts the
# package's executables (uav-landing and the nodes) on PATH.
_uav_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
# shellcheck disable=SC1091
source "$_uav_root/.venv/bin/activate"
export AMENT_PREFIX_PATH="$VIRTUAL_ENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
if [ -f "$_uav_root/install/setup.bash" ]; then
    # shellcheck disable=SC1091
    source "$_uav_root/install/setup.bash"
fi
export PATH="$_uav_root/install/uav_landing_vision/lib/uav_landing_vision:$PATH"
export MESA_SHADER_CACHE_DIR="${MESA_SHADER_CACHE_DIR:-$_uav_root/.cache/mesa}"
unset _uav_root
