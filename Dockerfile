# skyloc render service image: Debian 12 (Python 3.11, GDAL 3.6) + bpy 5.0.1 + the skyloc package.
#
#   docker build -t skyloc-service .
#   docker run --rm -p 8000:8000 -v skyloc-data:/data -e SKYLOC_TOKEN="$(openssl rand -hex 24)" skyloc-service
#
# The server listens on 0.0.0.0 inside the container, so it refuses to start without a token
# (SKYLOC_TOKEN, or --token-file with a mounted secret).  Job store, DEMs and results live in /data.
# For many machines: run `dask scheduler` / `dask worker --nthreads 1` from this same image with /data
# on a shared filesystem, and add `--scheduler tcp://scheduler:8786` to the command.  See docs/service.md.
FROM debian:bookworm-slim

ARG DEBIAN_FRONTEND=noninteractive
# python3.11 and GDAL from Debian; the X/GL libraries are what bpy (headless Blender) links against.
RUN apt-get update \
 && apt-get install -y --no-install-recommends \
      python3.11 python3.11-venv python3.11-dev build-essential \
      gdal-bin libgdal-dev \
      libx11-6 libxrender1 libxxf86vm1 libxfixes3 libxi6 libxkbcommon0 libsm6 libgl1 libegl1 libgomp1 \
      ca-certificates tini \
 && rm -rf /var/lib/apt/lists/*

RUN useradd --create-home --uid 10001 skyloc \
 && python3.11 -m venv /opt/skyloc \
 && /opt/skyloc/bin/pip install --no-cache-dir --upgrade pip wheel "setuptools>=67"
ENV PATH=/opt/skyloc/bin:$PATH \
    PYTHONUNBUFFERED=1 \
    NUMBA_CACHE_DIR=/tmp/numba-cache \
    SKYLOC_DATA_DIR=/data \
    SKYLOC_SCENES_DIR=/src/scenes

WORKDIR /src
COPY pyproject.toml README.md ./
COPY board ./board
COPY blender_addon ./blender_addon
COPY render_service ./render_service
COPY skyloc ./skyloc
COPY scenes ./scenes
# GDAL bindings must match the system library (3.6.2 on bookworm); bpy is the 'blender' extra.
RUN pip install --no-cache-dir ".[ground,blender]" \
 && pip install --no-cache-dir --no-build-isolation "GDAL==$(gdal-config --version)" \
 && python -c "from osgeo import gdal; import bpy, numba, zarr, dask.distributed, fastapi, render_service.main"

RUN mkdir -p /data && chown skyloc:skyloc /data
USER skyloc
VOLUME ["/data"]
EXPOSE 8000
HEALTHCHECK --interval=30s --timeout=5s CMD python -c "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=4)"
ENTRYPOINT ["tini", "--", "skyloc", "serve"]
CMD ["--host", "0.0.0.0", "--port", "8000", "--data", "/data"]
