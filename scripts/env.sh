# shellcheck shell=bash
# Source this file to use pvo from a shell:  source scripts/env.sh
# It activates the project venv (ROS 2 Jazzy from the ros-jazzy-* wheels), points the ament
# index and CMake at the wheels' prefix, and sources the colcon workspace when it is built.
_pvo_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
_pvo_venv="${_pvo_root}/.venv"
if [ ! -x "${_pvo_venv}/bin/python" ]; then
  echo "pvo: no virtual environment at ${_pvo_venv}; run 'make build' first" >&2
  return 1 2>/dev/null || exit 1
fi
export VIRTUAL_ENV="${_pvo_venv}"
case ":${PATH}:" in *":${_pvo_venv}/bin:"*) ;; *) export PATH="${_pvo_venv}/bin:${PATH}" ;; esac
# The wheels ship an ament index under the venv prefix but set no AMENT_PREFIX_PATH.
case ":${AMENT_PREFIX_PATH:-}:" in *":${_pvo_venv}:"*) ;;
  *) export AMENT_PREFIX_PATH="${_pvo_venv}${AMENT_PREFIX_PATH:+:${AMENT_PREFIX_PATH}}" ;; esac
case ":${CMAKE_PREFIX_PATH:-}:" in *":${_pvo_venv}:"*) ;;
  *) export CMAKE_PREFIX_PATH="${_pvo_venv}${CMAKE_PREFIX_PATH:+:${CMAKE_PREFIX_PATH}}" ;; esac
case ":${LD_LIBRARY_PATH:-}:" in *":${_pvo_venv}/lib:"*) ;;
  *) export LD_LIBRARY_PATH="${_pvo_venv}/lib${LD_LIBRARY_PATH:+:${LD_LIBRARY_PATH}}" ;; esac
export RMW_IMPLEMENTATION="${RMW_IMPLEMENTATION:-rmw_fastrtps_cpp}"
# Keep DDS discovery on this host unless the user asks for more.
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
export PVO_ROOT="${_pvo_root}"
if [ -f "${_pvo_root}/install/setup.bash" ]; then
  # shellcheck disable=SC1091
  source "${_pvo_root}/install/setup.bash"
fi
unset _pvo_root _pvo_venv
