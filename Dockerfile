# One image for the web server and the workers of a lab server (see docker-compose.yml).
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 PIP_NO_CACHE_DIR=1 MALLOC_ARENA_MAX=2
RUN useradd --create-home --uid 1000 fringelab
WORKDIR /app
COPY pyproject.toml README.md ./
COPY fringelab ./fringelab
COPY backend ./backend
COPY worker ./worker
COPY frontend ./frontend
RUN pip install -e . && mkdir -p /data && chown fringelab /data
USER fringelab
ENV FRINGELAB_DATA_DIR=/data FRINGELAB_HOST=0.0.0.0
EXPOSE 8000
CMD ["fringelab", "api"]
