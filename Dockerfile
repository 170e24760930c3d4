# tsdb-service: the history of a FIWARE deployment (QuantumLeap-compatible API on port 8668).
#
#   docker build -t tsdb-service:0.1.0 .
#   docker run -p 8668:8668 -v tsdb-data:/data tsdb-service:0.1.0
#
# The embedded DuckDB file lives in the /data volume; set TSDB_DB=postgresql://...
# to use PostgreSQL instead. Every TSDB_* setting of the documentation applies.
#
# Two stages. The first installs the package and its runtime dependencies (no
# test or benchmark extras) into a virtual environment and prunes what the
# service never loads (docker/prune-venv.sh); the runtime stage gets that
# environment only: no pip, no source tree, no build files. Size estimate and
# how it was made: docs/containers.md.
FROM python:3.11.13-slim-bookworm AS build

ENV PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1

WORKDIR /src
COPY pyproject.toml README.md ./
COPY migrations ./migrations
COPY tsdb_service ./tsdb_service
COPY docker/prune-venv.sh ./
RUN python -m venv /opt/tsdb \
    && /opt/tsdb/bin/pip install . \
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
