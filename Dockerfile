# One image for the API and the workers of the MoJu service (see docker-compose.yml).
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    MOJU_DATA_DIR=/data

WORKDIR /app

# Dependencies first, so that editing the code does not reinstall them.
COPY pyproject.toml README.md ./
COPY moju_core ./moju_core
COPY moju_viewer ./moju_viewer
COPY moju_cli ./moju_cli
COPY service ./service
COPY worker ./worker
RUN pip install ".[service]"

# Jobs are run by an unprivileged user; /data is the volume shared by the API and workers.
RUN useradd --create-home --uid 10001 moju && mkdir -p /data && chown moju /data
USER moju
VOLUME ["/data"]
EXPOSE 8000

# The API by default; docker-compose.yml runs the workers from the same image with
# `moju worker`.
CMD ["python", "-m", "service.uvicorn_server", "--host", "0.0.0.0", "--port", "8000"]
