#!/usr/bin/env bash
# Build the larns image on a machine without registry access:
#   1. wheels of the run-time dependencies (+ setuptools, wheel), fetched/built on the host into
#      build/wheels (pinned to the versions installed in .venv, so the image runs what the tests ran);
#   2. the local base image larns-base:bookworm (scripts/docker-base.sh, skipped if present);
#   3. the real Dockerfile with --build-arg BASE=larns-base:bookworm, installing from the wheels
#      (larns itself is built from the source tree inside the image).
#
#   scripts/docker-build.sh [--tag larns:latest] [--base IMAGE] [--force-base] [--no-wheels]
#
# The host Python must be CPython 3.11 (Debian bookworm's python3 in the base image is 3.11).
# With a registry, plain `docker build -t larns .` does the same from python:3.11-slim.
set -euo pipefail
cd "$(dirname "$0")/.."

TAG=${LARNS_IMAGE:-larns:latest}
BASE=${LARNS_BASE_IMAGE:-larns-base:bookworm}
FORCE_BASE=()
WHEELS=1
while [ $# -gt 0 ]; do
  case "$1" in
    --tag) TAG=$2; shift ;;
    --base) BASE=$2; shift ;;
    --force-base) FORCE_BASE=(--force) ;;
    --no-wheels) WHEELS=0 ;;
    -h|--help) sed -n '2,12p' "$0"; exit 0 ;;
    *) echo "docker-build.sh: unknown argument $1" >&2; exit 2 ;;
  esac
  shift
done

log() { echo "[docker-build] $*" >&2; }
now() { date +%s.%N; }
dt() { awk -v a="$1" -v b="$(now)" 'BEGIN{printf "%.1f", b-a}'; }

t0=$(now)
PY=${PYTHON:-.venv/bin/python}
WH=build/wheels
if [ "$WHEELS" = 1 ]; then
  t=$(now)
  "$PY" -c 'import sys; assert sys.version_info[:2] == (3, 11), "need CPython 3.11 on the host, got " + sys.version' \
    || { echo "docker-build.sh: set PYTHON=/path/to/python3.11 or use --no-wheels" >&2; exit 1; }
  reqs=$(mktemp); constraints=$(mktemp); trap 'rm -f "$reqs" "$constraints"' EXIT
  # the run-time dependencies of pyproject.toml (larns itself is built inside the image) ...
  "$PY" -c 'import tomllib; print("\n".join(tomllib.load(open("pyproject.toml", "rb"))["project"]["dependencies"]))' >"$reqs"
  # ... pinned to what the dev venv runs, so the image runs what the tests ran
  "$PY" -m pip freeze --exclude-editable 2>/dev/null | grep -viE '^(larns|-e |#)' >"$constraints" || true
  key=$(cat "$reqs" "$constraints" | sha1sum | cut -c1-16)
  if [ -f "$WH/.key-$key" ]; then
    log "wheelhouse up to date ($WH)"
  else
    rm -rf "$WH"; mkdir -p "$WH"
    "$PY" -m pip wheel -q --disable-pip-version-check -r "$reqs" "setuptools>=77" wheel -c "$constraints" -w "$WH"
    touch "$WH/.key-$key"
  fi
  log "wheels: $(ls "$WH" | wc -l) files, $(du -sh "$WH" | cut -f1) in $WH ($(dt "$t") s)"
else
  rm -rf "$WH"
fi

t=$(now)
scripts/docker-base.sh "${FORCE_BASE[@]}" --tag "$BASE"
log "base image $BASE ready ($(dt "$t") s)"

t=$(now)
mkdir -p build
old=$(docker image inspect -f '{{.Id}}' "$TAG" 2>/dev/null || true)
{
  # the build stages get tags of their own, so pruning stale ones keeps the current cache
  docker build --target runtime --build-arg BASE="$BASE" -t larns-build:runtime . &&
  docker build --target app --build-arg BASE="$BASE" -t larns-build:app . &&
  docker build --build-arg BASE="$BASE" -t "$TAG" .
} >build/docker-build.log 2>&1 || { tail -n 40 build/docker-build.log >&2; exit 1; }
new=$(docker image inspect -f '{{.Id}}' "$TAG")
# drop what this build made obsolete: the previous image and untagged build stages (ours only)
if [ -n "$old" ] && [ "$old" != "$new" ]; then docker rmi "$old" >/dev/null 2>&1 || true; fi
docker image prune -f --filter label=org.larns.stage=build >/dev/null 2>&1 || true
size=$(docker image inspect -f '{{.Size}}' "$TAG")
log "$(awk -v t="$TAG" -v s="$size" 'BEGIN{printf "image %s: %.0f MB", t, s/1e6}') ($(dt "$t") s)"
log "total $(dt "$t0") s"
