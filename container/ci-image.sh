#!/usr/bin/env bash
# Build the service's container image with podman on a Debian 12 machine with no Docker engine
# and no reachable container registry, then test a fresh container (tests/container/test_image.py).
# Run as root from the repository's root (.ci/run calls it). Prints the time of each phase.
#
#   EXCITE_IMAGE   tag to build (default localhost/excite:ci)
#   BASE_IMAGE     Debian + python3.11 base, bootstrapped with mmdebstrap when missing
#                  (default localhost/debian-python:bookworm)
#   BUILD_BASE_IMAGE  the same with gcc and Python's headers, the build stage's (default
#                  localhost/debian-python-dev:bookworm)
set -euo pipefail
cd "$(dirname "$0")/.."
image=${EXCITE_IMAGE:-localhost/excite:ci}
base=${BASE_IMAGE:-localhost/debian-python:bookworm}
build_base=${BUILD_BASE_IMAGE:-localhost/debian-python-dev:bookworm}
t0=$SECONDS
phase() { echo "ci-image: $1 (${SECONDS}s since start, +$((SECONDS - t0))s)"; t0=$SECONDS; }

export DEBIAN_FRONTEND=noninteractive
if ! command -v podman >/dev/null || ! command -v mmdebstrap >/dev/null; then
  apt-get update -qq
  # podman pulls conmon, runc (or crun), containernetworking-plugins (CNI bridge), iptables and
  # containers-common; nothing rootless (uidmap, slirp4netns, fuse-overlayfs) is needed as root
  apt-get install -y -qq --no-install-recommends podman runc mmdebstrap >/dev/null
fi
phase "podman $(podman --version | awk '{print $3}'), mmdebstrap installed"

# this sandbox's hard limits (nofile 20000, nproc 96365, no CAP_SYS_RESOURCE) are below podman's
# defaults for root: every container would fail with "error setting rlimit type 7/6"
export CONTAINERS_CONF=$PWD/container/containers.conf

if ! podman image exists "$base"; then
  container/mkbase.sh essential "$(mktemp -d)/debian-python.tar" "$base"
fi
phase "base image $base ($(podman image inspect --format '{{.Size}}' "$base") bytes)"
if ! podman image exists "$build_base"; then
  container/mkbase.sh essential "$(mktemp -d)/debian-python-dev.tar" "$build_base" gcc,libc6-dev,python3.11-dev
fi
phase "build stage's base image $build_base ($(podman image inspect --format '{{.Size}}' "$build_base") bytes)"

secret=()
ca=${PIP_CERT:-/etc/ssl/certs/ca-certificates.crt}  # the host's CA bundle (a TLS-inspecting proxy)
[ -s "$ca" ] && secret=(--secret "id=ca,src=$ca")
podman build --format docker "${secret[@]}" --build-arg BASE="$base" --build-arg BUILD_BASE="$build_base" \
  -t "$image" -f Dockerfile .
phase "image $image built ($(podman image inspect --format '{{.Size}}' "$image") bytes)"

EXCITE_IMAGE=$image python3 -m pytest -q -p no:cacheprovider --noconftest -rA tests/container/test_image.py
phase "container tested"
