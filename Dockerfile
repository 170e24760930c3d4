# tsdb-service: the history of a FIWARE deployment (QuantumLeap-compatible API on port 8668).
#
#   docker build -t tsdb-service:0.1.0 .
#   docker run -p 8668:8668 -v tsdb-data:/data tsdb-service:0.1.0
#
# The embedded DuckDB file lives in the /data volume; set TSDB_DB=postgresql://...
# to use PostgreSQL instead. Every TSDB_* setting of the README applies.
FROM python:3.11.13-slim-bookworm

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1

WORKDIR /src
COPY pyproject.toml README.md ./
COPY migrations ./migrations
COPY tsdb_service ./tsdb_service
RUN pip install . \
    && rm -rf /src \
    && useradd --system --uid 10001 --no-create-home --home-dir /data tsdb \
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
