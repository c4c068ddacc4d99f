# skyloc render service image: Debian 12 (Python 3.11, GDAL 3.6 from apt) + the skyloc package with its
# `ground` extra (FastAPI service, Dask, numba ray-marcher).  No bpy: the Blender renderer and
# dataset jobs answer 501 not_available on this image; the raymarch renderer does everything else.
#
#   make image                      # docker, podman or buildah, whichever works (scripts/image_build.sh)
#   docker build -t skyloc-service .
#   docker build --secret id=ca-bundle,src=/etc/ssl/certs/ca-certificates.crt -t skyloc-service .   # TLS proxy
#   docker run --rm -p 8000:8000 -v skyloc-data:/data -e SKYLOC_TOKEN="$(openssl rand -hex 24)" skyloc-service
#
# Roles (scripts/image_entrypoint.sh): `api` (default), `scheduler`, `worker`; compose.yaml runs
# API + scheduler + N workers.  Behind a TLS-inspecting proxy, its CA bundle is the build secret
# `ca-bundle`: apt and pip trust it during the build only (scripts/image_with_ca.sh), no layer holds
# it.  Package indexes are build arguments with public defaults.  See docs/service.md.
ARG BASE_IMAGE=debian:bookworm-slim

# ---------------------------------------------------------------------------------------------
FROM ${BASE_IMAGE} AS base
ARG APT_MIRROR=http://deb.debian.org/debian
ARG APT_SECURITY_MIRROR=http://deb.debian.org/debian-security
ARG DEBIAN_FRONTEND=noninteractive
COPY scripts/image_with_ca.sh /usr/local/bin/skyloc-with-ca
RUN chmod 0755 /usr/local/bin/skyloc-with-ca \
 && rm -f /etc/apt/sources.list /etc/apt/sources.list.d/* \
 && printf 'Types: deb\nURIs: %s\nSuites: bookworm bookworm-updates\nComponents: main\nSigned-By: /usr/share/keyrings/debian-archive-keyring.gpg\n\nTypes: deb\nURIs: %s\nSuites: bookworm-security\nComponents: main\nSigned-By: /usr/share/keyrings/debian-archive-keyring.gpg\n' \
      "$APT_MIRROR" "$APT_SECURITY_MIRROR" >/etc/apt/sources.list.d/debian.sources
RUN --mount=type=secret,id=ca-bundle \
    skyloc-with-ca apt-get update \
 && skyloc-with-ca apt-get install -y --no-install-recommends python3.11 ca-certificates \
 && apt-get clean && rm -rf /var/lib/apt/lists/* /var/cache/apt/*.bin /var/log/apt /var/log/dpkg.log

# ---------------------------------------------------------------------------------------------
FROM base AS builder
ARG DEBIAN_FRONTEND=noninteractive
ARG PIP_INDEX_URL=https://pypi.org/simple
ARG PIP_EXTRA_INDEX_URL=
ARG SKYLOC_EXTRAS=ground
ENV PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_DEFAULT_TIMEOUT=120
RUN --mount=type=secret,id=ca-bundle \
    skyloc-with-ca apt-get update \
 && skyloc-with-ca apt-get install -y --no-install-recommends python3.11-venv python3.11-dev build-essential libgdal-dev \
 && apt-get clean && rm -rf /var/lib/apt/lists/*
RUN --mount=type=secret,id=ca-bundle \
    python3.11 -m venv /opt/skyloc \
 && skyloc-with-ca /opt/skyloc/bin/pip install --upgrade pip wheel "setuptools>=67"
WORKDIR /src
# Dependencies first, from pyproject.toml alone (this layer is reused while only the source changes),
# at the versions of constraints.txt (those the test suite last passed with), with the GDAL bindings of
# the system library (3.6.2 on bookworm) built against it.
COPY pyproject.toml constraints.txt ./
RUN --mount=type=secret,id=ca-bundle \
    /opt/skyloc/bin/python -c 'import sys, tomllib; p = tomllib.load(open("pyproject.toml", "rb"))["project"]; \
extras = [e for e in sys.argv[1].split(",") if e]; \
print("\n".join(p["dependencies"] + [d for e in extras for d in p["optional-dependencies"][e]]))' \
      "$SKYLOC_EXTRAS" >/tmp/requirements.txt \
 && skyloc-with-ca /opt/skyloc/bin/pip install -c constraints.txt -r /tmp/requirements.txt \
 && skyloc-with-ca /opt/skyloc/bin/pip install --no-build-isolation "GDAL==$(gdal-config --version)" \
 && rm /tmp/requirements.txt
COPY README.md ./
COPY board ./board
COPY blender_addon ./blender_addon
COPY render_service ./render_service
COPY skyloc ./skyloc
RUN /opt/skyloc/bin/pip install --no-deps --no-build-isolation . \
 && /opt/skyloc/bin/pip check \
 && /opt/skyloc/bin/pip uninstall -y pip wheel setuptools \
 && find /opt/skyloc/lib/python3.11/site-packages -type d -name tests -prune -exec rm -rf {} +

# ---------------------------------------------------------------------------------------------
FROM base AS runtime
ARG DEBIAN_FRONTEND=noninteractive
# the shared libraries the venv links against (GDAL), tini as PID 1, openssl for making TLS files
RUN --mount=type=secret,id=ca-bundle \
    skyloc-with-ca apt-get update \
 && skyloc-with-ca apt-get install -y --no-install-recommends libgdal32 tini openssl \
 && apt-get clean && rm -rf /var/lib/apt/lists/* /var/cache/apt/*.bin /var/log/apt /var/log/dpkg.log \
 && rm /usr/local/bin/skyloc-with-ca
COPY --from=builder /opt/skyloc /opt/skyloc
COPY scenes /opt/skyloc/share/scenes
COPY scripts/image_entrypoint.sh /usr/local/bin/skyloc-role
RUN chmod 0755 /usr/local/bin/skyloc-role \
 && useradd --uid 10001 --user-group --create-home --shell /usr/sbin/nologin skyloc \
 && mkdir -p /data \
 && chown skyloc:skyloc /data \
 && /opt/skyloc/bin/python -c "from osgeo import gdal, gdal_array; import numba, zarr, cv2, dask.distributed, fastapi, uvicorn, render_service.main"
ENV PATH=/opt/skyloc/bin:$PATH \
    PYTHONUNBUFFERED=1 \
    NUMBA_CACHE_DIR=/tmp/numba-cache \
    SKYLOC_DATA_DIR=/data \
    SKYLOC_SCENES_DIR=/opt/skyloc/share/scenes
LABEL org.opencontainers.image.title="skyloc render service" \
      org.opencontainers.image.description="skyloc render service: API, Dask scheduler and worker roles (raymarch renderer, no bpy)" \
      org.opencontainers.image.licenses="Apache-2.0"
USER skyloc:skyloc
WORKDIR /home/skyloc
VOLUME ["/data"]
EXPOSE 8000 8786
HEALTHCHECK --interval=30s --timeout=5s --start-period=60s --retries=3 CMD ["skyloc-role", "health"]
ENTRYPOINT ["tini", "--", "skyloc-role"]
CMD ["api"]
