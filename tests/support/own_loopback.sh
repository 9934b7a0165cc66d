#!/usr/bin/env bash
# Runs a test in a network namespace of its own whose only interface is a loopback at 127.0.0.1.
# GigE Vision serves GVCP on port 3956 of an interface's own address (Aravis's fake camera will
# not bind 127.0.0.2), so on the machine's loopback one simulated camera at a time can run; in a
# namespace each test has its own, and the GigE tests run side by side. tests/CMakeLists.txt
# uses it only when it works here (unshare and ip; as root, or with unprivileged user
# namespaces), and serialises the tests on the lock "gvcp" otherwise.
set -euo pipefail
if [[ "$(id -u)" == 0 ]]; then
  ns=(unshare --net)
else
  ns=(unshare --net --map-root-user)
fi
# shellcheck disable=SC2016 # $@ is expanded by the inner shell
exec "${ns[@]}" -- bash -c 'ip link set lo up && exec "$@"' own_loopback "$@"
