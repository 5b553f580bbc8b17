# isorig service image: the same command as the README (bash scripts/run.sh), on the embedded defaults
# (simulated rig, SQLite in /data). docker compose runs it; see docker-compose.yml and docs/backend.md.
FROM python:3.11-slim

ENV PYTHONUNBUFFERED=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    ISORIG_HOST=0.0.0.0 \
    ISORIG_PORT=8000 \
    ISORIG_DATA_DIR=/data

WORKDIR /app
COPY pyproject.toml README.md ./
COPY sim ./sim
COPY backend ./backend
COPY isorig ./isorig
COPY frontend ./frontend
COPY scripts ./scripts

# setup.sh creates .venv and installs the project (as scripts/run.sh does on every start, fast once done);
# the postgres extra adds the PostgreSQL driver; the engine's kernels are compiled into numba's cache once.
RUN bash scripts/setup.sh \
 && .venv/bin/pip install -q -e ".[postgres]" \
 && .venv/bin/python -c "from sim.engine import warm_up; warm_up()" \
 && mkdir -p /data

VOLUME ["/data"]
EXPOSE 8000
CMD ["bash", "scripts/run.sh"]
