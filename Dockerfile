# The itnet serving image: onnxruntime + numpy + FastAPI, no torch (the `train` extra is not
# installed). The shipped models (itnet/models/*.onnx) are package data, so they are baked in.
#   docker build -t itnet .
#   docker run --rm -p 8000:8000 itnet
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1

WORKDIR /src
COPY pyproject.toml README.md ./
COPY itnet ./itnet
COPY model ./model
COPY export ./export
COPY service ./service
COPY clients ./clients
# itnet.scale (Ray Serve, batch) is part of the package; ray itself is not installed here.
COPY scale ./scale
# `.` without extras: the serving dependencies only (see [project] dependencies).
RUN pip install --no-cache-dir . \
    && python -c "import itnet.service.app" \
    && groupadd --gid 10001 itnet \
    && useradd --create-home --uid 10001 --gid 10001 --shell /usr/sbin/nologin itnet

USER 10001:10001
WORKDIR /home/itnet
EXPOSE 8000
HEALTHCHECK --interval=30s --timeout=5s --start-period=30s --retries=3 \
    CMD ["python", "-c", "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=4)"]
CMD ["itnet", "serve", "--host", "0.0.0.0"]
