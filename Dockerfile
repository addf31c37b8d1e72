# LARNS: one image for every role (station, aircraft, recorder, replay).
#
#   docker build -t larns .                      # from python:3.11-slim, dependencies from PyPI
#   scripts/docker-build.sh                      # offline: local Debian base + host-built wheels
#   docker run --rm larns --help
#   docker run --rm larns station --id 1 --scenario seed000
#
# BASE is any image with CPython >= 3.11 as `python3` (and the venv module). When the build
# context holds a wheelhouse in build/wheels (the dependencies of pyproject.toml plus setuptools
# and wheel, made by scripts/docker-build.sh), everything is installed from it with --no-index, so
# no network is needed; otherwise the dependencies come from PyPI. larns itself is always built
# from this source tree into a small layer of its own (/opt/larns-app), so editing the code
# neither reinstalls nor re-copies the dependencies. --build-arg WHEELHOUSE=none ignores a
# wheelhouse.
ARG BASE=python:3.11-slim

# 1. dependencies in a venv (cached until pyproject.toml or the wheelhouse change)
FROM ${BASE} AS deps
# build stages carry this label so scripts/docker-build.sh can prune their stale copies
LABEL org.larns.stage="build"
ARG WHEELHOUSE=auto
ENV PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_NO_CACHE_DIR=1 PYTHONDONTWRITEBYTECODE=1
COPY pyproject.toml build/wheel[s] /wheels/
RUN set -eu; \
    python3 -m venv /opt/larns; \
    python3 -c 'import tomllib; print("\n".join(tomllib.load(open("/wheels/pyproject.toml", "rb"))["project"]["dependencies"]))' \
        >/wheels/requirements.txt; \
    if [ "$WHEELHOUSE" != none ] && ls /wheels/*.whl >/dev/null 2>&1; then \
        echo "dependencies from the wheelhouse (no index)"; \
        set -- --no-index --find-links /wheels; \
    else \
        echo "dependencies from the package index"; \
        set --; \
    fi; \
    /opt/larns/bin/pip install "$@" "setuptools>=77" wheel -r /wheels/requirements.txt; \
    /opt/larns/bin/pip check; \
    # larns itself lives in /opt/larns-app (next stage), put on the venv's path by a .pth file
    echo /opt/larns-app >"$(/opt/larns/bin/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')/larns-app.pth"

# 2. the run-time venv: no pip/setuptools, no third-party test suites (also cached)
FROM deps AS runtime
RUN /opt/larns/bin/pip uninstall -y -q pip setuptools wheel \
 && find /opt/larns/lib -depth -type d -name tests -path '*/site-packages/*' -exec rm -rf {} +

# 3. larns from this source tree, in its own small layer
FROM deps AS app
COPY . /src
RUN /opt/larns/bin/pip install --no-index --no-deps --no-build-isolation --target /opt/larns-app /src \
 && rm -rf /opt/larns-app/bin/__pycache__ \
 && /opt/larns-app/bin/larns --version

FROM ${BASE}
LABEL org.opencontainers.image.title="larns" \
      org.opencontainers.image.description="LARNS emulator: station, aircraft, recorder and replay roles over Eclipse Zenoh"
RUN useradd --system --uid 10001 --user-group --create-home --home-dir /home/larns --shell /usr/sbin/nologin larns \
 && mkdir -p /runs && chown larns:larns /runs
ENV PATH=/opt/larns-app/bin:/opt/larns/bin:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin \
    PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    MPLBACKEND=Agg \
    MPLCONFIGDIR=/tmp/matplotlib
USER larns
WORKDIR /runs
# Zenoh peers listen here (tcp/0.0.0.0:7447)
EXPOSE 7447
# Healthy while a larns process is alive in the container (not a zombie, not stopped); works with
# and without an init process (compose runs the services with `init: true`).
HEALTHCHECK --interval=30s --timeout=5s --start-period=20s --retries=3 \
    CMD ["python3", "-S", "-c", "import glob, os, sys\ndef state(d):\n    try:\n        return open(d + '/cmdline', 'rb').read(), open(d + '/stat').read().rsplit(')', 1)[1].split()[0]\n    except (OSError, IndexError):\n        return b'', 'X'\nme = '/proc/%d' % os.getpid()\nprocs = [state(d) for d in glob.glob('/proc/[0-9]*') if d != me]\nsys.exit(0 if any(b'/bin/larns' in c and s not in 'ZTtXx' for c, s in procs) else 1)"]
ENTRYPOINT ["larns"]
CMD ["--help"]
# the big dependency layer first (cached), then the small larns layer
COPY --from=runtime /opt/larns /opt/larns
COPY --from=app /opt/larns-app /opt/larns-app
