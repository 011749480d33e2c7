# navlab: Streamlit lab for robust/adaptive Kalman filters.
#
# Build:  docker build -t navlab .
# Run:    docker run --rm -p 8501:8501 navlab            -> http://localhost:8501
# Data:   the real data sets are NOT in the image; mount them read-only and point the app at them:
#         docker run --rm -p 8501:8501 -v /path/to/shared/data:/data:ro -e NAVLAB_DATA=/data navlab
# Extra streamlit flags are appended to the ENTRYPOINT (the last one wins).
# No Docker engine here? ../shared/tools/verify-docker.sh . builds and runs it with buildah/podman,
# passing a locally built stand-in as BASE_IMAGE.
ARG BASE_IMAGE=python:3.11-slim
FROM ${BASE_IMAGE}

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    VIRTUAL_ENV=/opt/venv \
    PATH=/opt/venv/bin:$PATH \
    STREAMLIT_SERVER_HEADLESS=true \
    STREAMLIT_BROWSER_GATHER_USAGE_STATS=false \
    STREAMLIT_SERVER_FILE_WATCHER_TYPE=none \
    NAVLAB_DATA=/data \
    NUMBA_CACHE_DIR=/opt/numba-cache

# unprivileged runtime user (numeric uid/gid 1000; code stays root-owned and read-only for it)
RUN groupadd --gid 1000 app \
    && useradd --uid 1000 --gid 1000 --create-home --shell /usr/sbin/nologin app

WORKDIR /app

# dependency layer first: editing the code does not reinstall the dependencies
COPY requirements.txt ./
RUN python -m venv /opt/venv \
    && pip install --no-cache-dir -r requirements.txt

COPY .streamlit/ .streamlit/
COPY navlab/ navlab/
COPY pages/ pages/
COPY app.py ./

# compile navlab's numba kernels now (a few seconds each), not on the app's first click; the cache
# lives outside the read-only code folder and stays writable for uid 1000 (a new CPU recompiles)
RUN python -m navlab.warmup && chown -R 1000:1000 /opt/numba-cache

USER 1000:1000
EXPOSE 8501

# python:*-slim has no curl. /_stcore/health answers "ok"; any other path (e.g. /healthz) also
# answers 200 with the SPA page, so compare the body. Proxies are bypassed for the loopback request.
HEALTHCHECK --interval=30s --timeout=5s --start-period=30s --retries=3 \
    CMD ["python", "-c", "import sys, urllib.request as u; r = u.build_opener(u.ProxyHandler({})).open('http://127.0.0.1:8501/_stcore/health', timeout=4); sys.exit(0 if r.read().decode().strip() == 'ok' else 1)"]

ENTRYPOINT ["streamlit", "run", "app.py", "--server.port=8501", "--server.address=0.0.0.0"]
