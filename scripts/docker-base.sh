#!/usr/bin/env bash
# Build the local base image larns-base:bookworm without any container registry:
# debootstrap a minimal Debian bookworm with python3 + venv, then `docker import` it.
#
#   scripts/docker-base.sh [--force] [--tag NAME:TAG]
#
# Environment:
#   LARNS_DEBIAN_MIRROR  Debian mirror URL (default: the first .../debian URI in /etc/apt sources,
#                        else http://deb.debian.org/debian)
#   LARNS_BASE_IMAGE     image tag (default larns-base:bookworm; --tag overrides)
#
# Idempotent: does nothing when the image already exists, unless --force. Needs root (debootstrap).
# The resulting image has Debian's CPython 3.11 at /usr/bin/python3, like python:3.11-slim has at
# /usr/local/bin/python3, so wheels built on a CPython 3.11 host install into it.
set -euo pipefail

TAG=${LARNS_BASE_IMAGE:-larns-base:bookworm}
FORCE=0
while [ $# -gt 0 ]; do
  case "$1" in
    --force) FORCE=1 ;;
    --tag) TAG=$2; shift ;;
    -h|--help) sed -n '2,14p' "$0"; exit 0 ;;
    *) echo "docker-base.sh: unknown argument $1" >&2; exit 2 ;;
  esac
  shift
done

log() { echo "[docker-base] $*" >&2; }

if [ "$FORCE" = 0 ] && docker image inspect "$TAG" >/dev/null 2>&1; then
  log "$TAG already exists (use --force to rebuild)"
  exit 0
fi

if [ "$(id -u)" != 0 ]; then
  echo "docker-base.sh: debootstrap needs root; run with sudo" >&2
  exit 1
fi

find_mirror() {
  local f
  for f in /etc/apt/sources.list /etc/apt/sources.list.d/*.list /etc/apt/sources.list.d/*.sources; do
    [ -r "$f" ] || continue
    # one-line format: "deb [opts] URL suite ..."; deb822 format: "URIs: URL"
    grep -hoE '(URIs:[[:space:]]*|^deb[[:space:]]+(\[[^]]*\][[:space:]]+)?)https?://[^[:space:]]+/debian/?([[:space:]]|$)' "$f" \
      | grep -oE 'https?://[^[:space:]]+' | head -n1
  done | head -n1
}
MIRROR=${LARNS_DEBIAN_MIRROR:-$(find_mirror || true)}
MIRROR=${MIRROR:-http://deb.debian.org/debian}

start=$(date +%s.%N)

if ! command -v debootstrap >/dev/null 2>&1; then
  log "installing debootstrap with apt-get"
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq debootstrap >/dev/null
fi

ROOT=$(mktemp -d /var/tmp/larns-rootfs.XXXXXX)
cleanup() { umount -R "$ROOT/proc" "$ROOT/sys" 2>/dev/null || true; rm -rf "$ROOT"; }
trap cleanup EXIT

log "debootstrap bookworm (minbase + python3, python3-venv, ca-certificates) from $MIRROR"
debootstrap --variant=minbase --include=python3,python3-venv,ca-certificates \
  bookworm "$ROOT" "$MIRROR" >"$ROOT.log" 2>&1 || { tail -n 30 "$ROOT.log" >&2; rm -f "$ROOT.log"; exit 1; }
rm -f "$ROOT.log"

# Slim down: package caches, docs, man pages, locales (C.UTF-8 is built in), logs.
rm -rf "$ROOT"/var/cache/apt/archives/*.deb "$ROOT"/var/cache/apt/*.bin "$ROOT"/var/lib/apt/lists/* \
  "$ROOT"/usr/share/doc/* "$ROOT"/usr/share/man/* "$ROOT"/usr/share/info/* \
  "$ROOT"/usr/share/locale/* "$ROOT"/var/log/*.log "$ROOT"/var/log/apt/* "$ROOT"/tmp/*
# The container gets its own resolv.conf/hosts from Docker.
: >"$ROOT/etc/resolv.conf"
echo "deb $MIRROR bookworm main" >"$ROOT/etc/apt/sources.list"

log "docker import -> $TAG"
tar --numeric-owner -C "$ROOT" -c . | docker import \
  --change 'ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
  --change 'ENV LANG=C.UTF-8' \
  --change 'ENV PYTHONDONTWRITEBYTECODE=1' \
  --change 'CMD ["/bin/bash"]' \
  --message "debootstrap bookworm minbase + python3 (scripts/docker-base.sh)" \
  - "$TAG" >/dev/null

end=$(date +%s.%N)
size=$(docker image inspect -f '{{.Size}}' "$TAG")
log "$(awk -v t="$TAG" -v a="$start" -v b="$end" -v s="$size" 'BEGIN{printf "built %s in %.1f s, size %.0f MB", t, b-a, s/1e6}')"
docker run --rm "$TAG" python3 -c 'import sys, venv, ssl; print("[docker-base] python", sys.version.split()[0])' >&2
