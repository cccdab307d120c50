#!/usr/bin/env bash
# Debian packages that some tests and scripts need outside Python, one named set at a time.
#
#   scripts/install_debian.sh slurm       SLURM and munge (scripts/provision_slurm.sh uses it)
#   scripts/install_debian.sh chromium    headless Chromium and a font, for
#                                         scripts/screenshot_report.py
#   scripts/install_debian.sh slurm chromium
#
# A set whose commands are all present already is left alone (no apt-get, no root needed).
# Exit codes: 0 every set present, 2 unknown set, 3 cannot install here (the reason is the
# last line of stderr).
set -euo pipefail

cannot() { echo "cannot install $1: $2" >&2; exit 3; }

# set name -> commands that show it is installed | Debian packages that provide them
commands_of() {
  case "$1" in
    slurm) echo "slurmctld slurmd sbatch munged ip nsenter" ;;
    chromium) echo "chromium" ;;
    *) return 1 ;;
  esac
}
packages_of() {
  case "$1" in
    slurm) echo "slurmctld slurmd slurm-client munge iproute2 util-linux" ;;
    chromium) echo "chromium fonts-dejavu-core" ;;  # a font, or text draws as boxes
  esac
}

[ $# -gt 0 ] || { echo "usage: $0 SET... (sets: slurm, chromium)" >&2; exit 2; }
updated=
for set in "$@"; do
  cmds=$(commands_of "$set") || { echo "unknown set: $set (sets: slurm, chromium)" >&2; exit 2; }
  missing=
  for cmd in $cmds; do
    command -v "$cmd" >/dev/null || missing="$missing $cmd"
  done
  [ -z "$missing" ] && continue
  pkgs=$(packages_of "$set")
  [ "$(id -u)" = 0 ] || cannot "$set" "needs root for apt-get (missing:$missing)"
  command -v apt-get >/dev/null || cannot "$set" "no apt-get to install Debian's $pkgs"
  export DEBIAN_FRONTEND=noninteractive
  if [ -z "$updated" ]; then
    apt-get update -qq >/dev/null || cannot "$set" "apt-get update failed"
    updated=1
  fi
  # shellcheck disable=SC2086
  apt-get install -y -qq --no-install-recommends $pkgs >/dev/null \
    || cannot "$set" "apt-get install $pkgs failed"
  for cmd in $cmds; do
    command -v "$cmd" >/dev/null || cannot "$set" "$cmd is still missing after apt-get install"
  done
done
