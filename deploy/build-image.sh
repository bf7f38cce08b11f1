#!/usr/bin/env bash
# Build the image simple-message-stack:VERSION (VERSION: the project's, from pyproject.toml) with
# podman, or docker when there is no podman, from deploy/Containerfile.
#
# It needs no container registry and no package index inside the build:
#   - the base image debian:bookworm-slim, when it is not there yet, is made from Debian's packages
#     with mmdebstrap (a minbase bookworm, slimmed as the official one: no manuals, no translations)
#     and imported under that name;
#   - the project and its dependencies (the web extra) come from a wheelhouse built here with pip,
#     for the image's Python (CPython 3.11 on glibc), and are installed in the image with --no-index.
# Inside the build only apt-get reaches out, to Debian's mirror, for python3.
#
# Usage: deploy/build-image.sh [ENGINE BUILD OPTIONS...]
#        deploy/build-image.sh --print-tag     (the image's name, built or not)
# Environment:
#   ENGINE         podman or docker (default: podman if installed, else docker)
#   PYTHON         the Python that builds the wheelhouse (default: python3)
#   DEBIAN_MIRROR  mmdebstrap's mirror: a URL or a sources file (default: mmdebstrap's, deb.debian.org)
#   IMAGE          the name to tag (default: simple-message-stack)
# Prints the image's name on the last line of stdout.
set -euo pipefail

here=$(cd "$(dirname "$0")" && pwd)
root=$(dirname "$here")
PYTHON=${PYTHON:-python3}
IMAGE=${IMAGE:-simple-message-stack}
BASE=debian:bookworm-slim

say() { echo "== $*" >&2; }

version=$("$PYTHON" -c 'import sys, tomllib; print(tomllib.load(open(sys.argv[1], "rb"))["project"]["version"])' \
    "$root/pyproject.toml")
tag="$IMAGE:$version"

if [ "${1:-}" = --print-tag ]; then
    echo "$tag"
    exit 0
fi

if [ -z "${ENGINE:-}" ]; then
    if command -v podman >/dev/null 2>&1; then
        ENGINE=podman
    elif command -v docker >/dev/null 2>&1 && docker info >/dev/null 2>&1; then
        ENGINE=docker
    else
        echo "build-image.sh: neither podman nor a running docker found (apt-get install podman)" >&2
        exit 2
    fi
fi

# Explicit limits for the build's containers, within this shell's own hard limits: where the
# sandbox lacks CAP_SYS_RESOURCE, the runtime's defaults (above them) cannot be set.
limit() { # limit FLAG CAP: the hard limit of ulimit -FLAG, at most CAP
    local v
    v=$(ulimit -H "-$1")
    if [ "$v" = unlimited ] || [ "$v" -gt "$2" ]; then v=$2; fi
    echo "$v"
}
nofile=$(limit n 65536)
nproc=$(limit u 4096)
engine_opts=(--ulimit "nofile=$nofile:$nofile" --ulimit "nproc=$nproc:$nproc")
if [ "$ENGINE" = podman ]; then
    # the docker format keeps HEALTHCHECK (the OCI format has none)
    engine_opts+=(--format docker)
fi

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

base_exists() {
    if [ "$ENGINE" = podman ]; then
        podman image exists "$BASE"
    else
        docker image inspect "$BASE" >/dev/null 2>&1
    fi
}

if ! base_exists; then
    say "$BASE is not here: making it with mmdebstrap from Debian's packages"
    if ! command -v mmdebstrap >/dev/null 2>&1; then
        echo "build-image.sh: $BASE is missing and mmdebstrap is not installed (apt-get install mmdebstrap)" >&2
        exit 2
    fi
    # the official slim image's exclusions (debuerreotype's slimify), kept in the image's dpkg.cfg.d
    # so that what the Containerfile installs is slim too
    slim=()
    for path in /usr/share/doc/\* /usr/share/man/\* /usr/share/info/\* /usr/share/groff/\* \
        /usr/share/lintian/\* /usr/share/linda/\* /usr/share/locale/\*; do
        slim+=("--dpkgopt=path-exclude=$path")
    done
    slim+=("--dpkgopt=path-include=/usr/share/doc/*/copyright" "--dpkgopt=path-include=/usr/share/locale/locale.alias")
    mirror=()
    if [ -n "${DEBIAN_MIRROR:-}" ]; then mirror=("$DEBIAN_MIRROR"); fi
    # merged /usr by mmdebstrap's hook, as the official image (not by the usrmerge package and its perl)
    mmdebstrap --variant=minbase --format=tar --hook-dir=/usr/share/mmdebstrap/hooks/merged-usr \
        "${slim[@]}" bookworm "$work/base.tar" "${mirror[@]}" >&2
    "$ENGINE" import --change 'CMD ["bash"]' "$work/base.tar" "$BASE" >&2
    rm -f "$work/base.tar"
fi

say "wheelhouse: simple-message-stack $version [web] for CPython 3.11"
context="$work/context"
mkdir -p "$context/wheels"
"$PYTHON" -m pip wheel --quiet --no-deps --wheel-dir "$context/wheels" "$root" >&2
wheels=("$context/wheels/simple_message_stack-$version"-*.whl)
platforms=()
arch=$(uname -m)
for minor in $(seq 36 -1 17); do # bookworm's glibc is 2.36
    platforms+=(--platform "manylinux_2_${minor}_$arch")
done
platforms+=(--platform "manylinux2014_$arch")
"$PYTHON" -m pip download --quiet --only-binary=:all: --python-version 3.11 --implementation cp --abi cp311 \
    "${platforms[@]}" --dest "$context/wheels" "${wheels[0]}[web]" >&2
cp "$here/Containerfile" "$context/Containerfile"
install -m 0755 "$here/healthcheck.py" "$context/healthcheck.py"

say "$ENGINE build $tag"
"$ENGINE" build "${engine_opts[@]}" --build-arg "VERSION=$version" --tag "$tag" "$@" "$context" >&2
# the build stage and the image this tag named before are left untagged: remove them (ours only)
"$ENGINE" image prune --force --filter "label=org.opencontainers.image.title=simple-message-stack" >/dev/null
echo "$tag"
