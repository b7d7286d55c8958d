# Source this file (bash) to use aruco_abs_orient from this checkout:
#   source tools/env.sh
# It puts the venv first on PATH (Debian's python with the pinned numpy/OpenCV) and sources the
# catkin workspace built by `make setup` (outside the repository, see tools/paths.sh; it overlays
# robot_localization when that was built). $AAO_WORKSPACE tells where it is.
_aao_root=$(cd -- "$(dirname -- "${BASH_SOURCE[0]}")/.." && pwd -P)
# shellcheck disable=SC1091
source "$_aao_root/tools/paths.sh"
_aao_ws=$(aao_workspace "$_aao_root")
if [[ ! -f $_aao_ws/devel/setup.bash ]]; then
  echo "tools/env.sh: $_aao_ws/devel/setup.bash is missing: run 'make setup' first" >&2
  return 1 2>/dev/null || exit 1
fi
unset PYTHONHOME PYENV_VERSION
# shellcheck disable=SC1091
source "$_aao_ws/devel/setup.bash"
export PATH=$_aao_root/.venv/bin:/usr/bin:/bin:/usr/sbin:/sbin:$PATH
export ROS_HOSTNAME=${ROS_HOSTNAME:-localhost}
export MPLBACKEND=Agg
export AAO_WORKSPACE=$_aao_ws
unset _aao_root _aao_ws
