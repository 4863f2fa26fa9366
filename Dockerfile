# syntax=docker/dockerfile:1
# excite HTTP service: one installed copy of the code, its native module (the evaluator's
# compiled loops) built at install and the optimizer's model compiled at build time, non-root,
# health-checked. Nothing is run at build to fill a cache: a container starts with what it needs.
#
#   podman build --format docker -t excite -f Dockerfile \
#       --secret id=ca,src=/etc/ssl/certs/ca-certificates.crt .      # the CA only where pip needs it
#   podman run -d -p 8000:8000 -v excite-data:/data excite
#
# BASE: a Debian 12 image with python3.11 + python3-venv, useradd and libstdc++6; where no
# registry is reachable, container/mkbase.sh bootstraps one with mmdebstrap
# (localhost/debian-python:bookworm). python:3.11-slim-bookworm should do too (not tried here).
# BUILD_BASE: the same with a C compiler and Python's headers (gcc, libc6-dev, python3.11-dev) for
# the build stage (localhost/debian-python-dev:bookworm: `container/mkbase.sh essential OUT TAG
# gcc,libc6-dev,python3.11-dev`; python:3.11-bookworm has them).
ARG BASE=localhost/debian-python:bookworm
ARG BUILD_BASE=localhost/debian-python-dev:bookworm

# ---- build: a venv with excite and its dependencies ----------------------------------------
FROM ${BUILD_BASE} AS build
ENV PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_ROOT_USER_ACTION=ignore \
    PYTHONDONTWRITEBYTECODE=1
RUN python3 -m venv /opt/excite
# dependencies first (own layer: a change of the code does not download them again). An empty
# package of the same metadata pulls exactly pyproject's dependencies.
COPY pyproject.toml README.md /src/
RUN --mount=type=secret,id=ca,target=/run/secrets/ca \
    if [ -s /run/secrets/ca ]; then export PIP_CERT=/run/secrets/ca; fi; \
    /opt/excite/bin/pip install /src && /opt/excite/bin/pip uninstall -y excite
COPY setup.py MANIFEST.in /src/
COPY excite /src/excite
COPY api /src/api
COPY container/slim.py /src/container/slim.py
# excite itself, non-editable (no source tree left beside it; its native module compiled by pip);
# then drop what nothing imports
RUN --mount=type=secret,id=ca,target=/run/secrets/ca \
    if [ -s /run/secrets/ca ]; then export PIP_CERT=/run/secrets/ca; fi; \
    /opt/excite/bin/pip install --no-deps /src \
    && /opt/excite/bin/python -m pip uninstall -q -y pip setuptools \
    && /opt/excite/bin/python /src/container/slim.py /opt/excite/lib/python3.11/site-packages \
    && find /opt/excite -exec touch -h -d @1700000000 {} + \
    && /opt/excite/bin/python -m compileall -q -f -j0 --invalidation-mode checked-hash \
        /opt/excite/lib/python3.11/site-packages
# Above: one whole-second timestamp for every file of the install, so that no copy or export of
# the layer can change it, and bytecode checked by hash, not by mtime (pip wrote timestamp .pyc
# files; after the touch they would be stale and every start would compile ~1100 modules from
# source again).
# The optimizer's model and kinematics for the service's default problem (robotaxi, 90 s,
# 80 × 50 m) compiled to C (excite.plan.compiled: ~2.5 min on 2 idle cores); the cache is keyed
# by the installed sources, so the runtime finds it. Other shapes run in CasADi's virtual machine.
RUN EXCITE_CACHE_DIR=/opt/excite-cache /opt/excite/bin/python -c "from excite.plan import OptimizeSettings; \
from excite.plan.transcription import prepare; from excite.rig.config import load_rig; \
rig = load_rig('robotaxi'); print('the optimizer for robotaxi, 90 s:', *prepare(rig, OptimizeSettings().for_rig(rig)))"

# ---- runtime ---------------------------------------------------------------------------------
FROM ${BASE}
ENV PATH=/opt/excite/bin:$PATH \
    PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    HOME=/var/lib/excite \
    MPLCONFIGDIR=/var/cache/excite/matplotlib \
    EXCITE_CACHE_DIR=/var/cache/excite/excite \
    EXCITE_DB_PATH=/data/excite-jobs.sqlite3
RUN useradd --system --uid 10001 --user-group --home-dir /var/lib/excite --create-home \
        --shell /usr/sbin/nologin excite \
    && install -d -o excite -g excite /data /var/cache/excite /var/cache/excite/matplotlib
COPY --from=build /opt/excite /opt/excite
COPY --from=build --chown=excite:excite /opt/excite-cache /var/cache/excite/excite
COPY container/dask.yaml /opt/excite/etc/dask/excite.yaml
USER excite
WORKDIR /var/lib/excite
# matplotlib's list of the image's fonts (written to $MPLCONFIGDIR; else its first plot builds it)
RUN python -c "import matplotlib.font_manager"
VOLUME ["/data"]
EXPOSE 8000
HEALTHCHECK --interval=10s --timeout=5s --start-period=30s --retries=3 \
    CMD ["python", "-c", "import sys, urllib.request; sys.exit(0 if urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=4).status == 200 else 1)"]
CMD ["excite", "serve", "--host", "0.0.0.0", "--port", "8000"]
