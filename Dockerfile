# tsdb-service: the history of a FIWARE deployment (QuantumLeap-compatible API on port 8668).
#
#   docker build -t tsdb-service:0.1.0 .
#   docker run -p 8668:8668 -v tsdb-data:/data tsdb-service:0.1.0
#
# The embedded DuckDB file lives in the /data volume; set TSDB_DB=postgresql://...
# to use PostgreSQL instead. Every TSDB_* setting of the documentation applies.
#
# Two stages. The first installs the runtime dependencies from
# requirements.lock (every one, direct and transitive, pinned with the hashes
# of its files: pip refuses anything else) into a virtual environment, builds
# the package's wheel with the build backend of requirements-build.lock,
# installs it without resolving anything, checks that nothing is missing, and
# prunes what the service never loads (docker/prune-venv.sh). The runtime
# stage gets that environment only: no pip, no source tree, no build files.
# Regenerate the lock files after changing a pin: sh docker/lock.sh.
# Reproducible builds and the image's size: docs/containers.md.
FROM python:3.11.13-slim-bookworm AS build

ENV PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1

WORKDIR /src
COPY requirements.lock requirements-build.lock ./
RUN python -m venv /opt/tsdb \
    && /opt/tsdb/bin/pip install --require-hashes --no-deps -r requirements.lock \
    && python -m venv /opt/build \
    && /opt/build/bin/pip install --require-hashes --no-deps -r requirements-build.lock
COPY pyproject.toml README.md ./
COPY migrations ./migrations
COPY tsdb_service ./tsdb_service
COPY docker/prune-venv.sh ./
RUN /opt/build/bin/pip wheel --no-deps --no-build-isolation --wheel-dir dist . \
    && /opt/tsdb/bin/pip install --no-deps dist/*.whl \
    && /opt/tsdb/bin/pip check \
    && sh prune-venv.sh /opt/tsdb/lib/python3.11/site-packages

FROM python:3.11.13-slim-bookworm

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PATH=/opt/tsdb/bin:$PATH

COPY --from=build /opt/tsdb /opt/tsdb
RUN useradd --system --uid 10001 --no-create-home --home-dir /data tsdb \
    && mkdir /data \
    && chown tsdb /data

USER tsdb
WORKDIR /data
ENV TSDB_DB=/data/tsdb.duckdb \
    TSDB_HOST=0.0.0.0 \
    TSDB_PORT=8668
VOLUME ["/data"]
EXPOSE 8668

HEALTHCHECK --interval=10s --timeout=3s --start-period=30s --retries=3 \
    CMD ["python", "-c", "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8668/health', timeout=2)"]

ENTRYPOINT ["tsdb-service"]
CMD ["serve"]
