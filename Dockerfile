# LARNS: one image for every role (station, aircraft, recorder, replay).
#
#   docker build -t larns .                      # from python:3.11-slim, dependencies from PyPI
#   scripts/docker-build.sh                      # offline: local Debian base + host-built wheels
#   docker run --rm larns --help
#   docker run --rm larns station --id 1 --scenario seed000
#
# BASE is any image with CPython >= 3.11 as `python3` (and the venv module). When the build
# context holds a wheelhouse in build/wheels (made by `pip wheel . -w build/wheels`, see
# scripts/docker-build.sh), larns and all its dependencies are installed from it with
# --no-index, so no network is needed; otherwise larns is built from source and its
# dependencies come from PyPI. Pass --build-arg WHEELHOUSE=none to ignore a wheelhouse.
ARG BASE=python:3.11-slim

FROM ${BASE} AS build
ARG WHEELHOUSE=build/wheels
ENV PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_NO_CACHE_DIR=1 PYTHONDONTWRITEBYTECODE=1
COPY . /src
RUN set -eu; \
    python3 -m venv /opt/larns; \
    if [ "$WHEELHOUSE" != none ] && ls /src/"$WHEELHOUSE"/larns-*.whl >/dev/null 2>&1; then \
        echo "installing larns from the wheelhouse /src/$WHEELHOUSE (no index)"; \
        /opt/larns/bin/pip install --no-index --find-links /src/"$WHEELHOUSE" larns; \
    else \
        echo "installing larns from source, dependencies from the package index"; \
        /opt/larns/bin/pip install /src; \
    fi; \
    /opt/larns/bin/pip uninstall -y -q pip setuptools wheel 2>/dev/null || true; \
    # test suites of third-party packages are dead weight at run time
    find /opt/larns/lib -depth -type d -name tests -path '*/site-packages/*' -exec rm -rf {} +; \
    /opt/larns/bin/larns --version

FROM ${BASE}
LABEL org.opencontainers.image.title="larns" \
      org.opencontainers.image.description="LARNS emulator: station, aircraft, recorder and replay roles over Eclipse Zenoh"
RUN useradd --system --uid 10001 --user-group --create-home --home-dir /home/larns --shell /usr/sbin/nologin larns \
 && mkdir -p /runs && chown larns:larns /runs
COPY --from=build /opt/larns /opt/larns
ENV PATH=/opt/larns/bin:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin \
    PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    MPLBACKEND=Agg \
    MPLCONFIGDIR=/tmp/matplotlib
USER larns
WORKDIR /runs
# Zenoh peers listen here (tcp/0.0.0.0:7447)
EXPOSE 7447
# The container's main process (PID 1, the larns command) must be alive: not a zombie, not stopped.
HEALTHCHECK --interval=30s --timeout=5s --start-period=20s --retries=3 \
    CMD ["python3", "-S", "-c", "import sys; s = open('/proc/1/stat').read().rsplit(')', 1)[1].split()[0]; c = open('/proc/1/cmdline').read(); sys.exit(0 if s not in 'ZTtX' and 'larns' in c else 1)"]
ENTRYPOINT ["larns"]
CMD ["--help"]
