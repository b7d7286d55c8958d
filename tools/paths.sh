# Sourced by tools/setup.sh and tools/env.sh: where the catkin workspace of this checkout lives.
# It is outside the repository on purpose: rosrun/roslaunch search a package's directory with
# `find -L`, and a workspace inside the repository (whose src/ links back to it) is a loop that
# makes every node name ambiguous. One workspace per checkout (hash of its path); AAO_WS overrides.
aao_workspace() {
  local root=$1
  echo "${AAO_WS:-${XDG_CACHE_HOME:-${HOME:-/root}/.cache}/aruco_abs_orient/ws-$(printf %s "$root" | sha1sum | cut -c1-12)}"
}
