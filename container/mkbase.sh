#!/bin/bash
# Bootstrap a minimal Debian 12 (bookworm) root filesystem with Debian's python3.11 (+venv) and
# import it into podman as a local image (no registry needed).
# usage: mkbase.sh [VARIANT] [OUT.tar] [TAG] [EXTRA]   VARIANT: essential (default, no apt) | minbase
#   EXTRA: further packages, comma-separated (the Dockerfile's build stage:
#   gcc,libc6-dev,python3.11-dev, the C compiler and Python's headers for excite's native module
#   and the optimizer's model)
set -euo pipefail
variant=${1:-essential}; out=${2:-debian-python.tar}; tag=${3:-localhost/debian-python:bookworm}
extra=${4:-}
# apt sources: this machine's own (deb822 file, pasted into the chroot as it is: the mirror and
# suites apt uses here, bookworm + updates + security), else mmdebstrap's default mirror
sources=${DEBIAN_SOURCES:-/etc/apt/sources.list.d/debian.sources}
[ -s "$sources" ] || sources=
# passwd: useradd (minbase has it, essential not); libstdc++6: the manylinux wheels (casadi,
# pyproj, ...) link the system's C++ runtime (minbase has it through apt, essential not)
include=python3,python3-venv,ca-certificates,passwd,libstdc++6${extra:+,$extra}
# merged-usr hook: /bin -> usr/bin symlinks + the real usr-is-merged package; without it apt
# satisfies init-system-helpers' "usrmerge | usr-is-merged" with usrmerge, which drags in perl
# (perl-modules + libperl: ~48 MB)
mmdebstrap --variant="$variant" --hook-dir=/usr/share/mmdebstrap/hooks/merged-usr \
  --include="$include" \
  --dpkgopt='path-exclude=/usr/share/man/*' \
  --dpkgopt='path-exclude=/usr/share/locale/*' \
  --dpkgopt='path-include=/usr/share/locale/locale.alias' \
  --dpkgopt='path-exclude=/usr/share/doc/*' \
  --dpkgopt='path-include=/usr/share/doc/*/copyright' \
  --dpkgopt='path-exclude=/usr/share/info/*' \
  --dpkgopt='path-exclude=/usr/share/lintian/*' \
  --customize-hook='rm -rf "$1"/var/log/* "$1"/var/cache/debconf/*-old "$1"/var/lib/dpkg/*-old' \
  bookworm "$out" ${sources:+"$sources"}
podman import --change 'CMD ["/usr/bin/python3"]' --change 'ENV LANG=C.UTF-8' "$out" "$tag" >/dev/null
podman image inspect --format '{{.Id}} {{.Size}}' "$tag"
