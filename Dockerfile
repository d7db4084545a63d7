# One image for every service of docker-compose.yml (ray-head, ray-worker, api, create-bucket):
# a Ray cluster needs the same Python and Ray on every node, and the workers unpickle the
# executor's tasks, so they need the same neuenh too.
#
#   docker build -t neuenh .                                        # CPU torch (the default)
#   docker build -t neuenh:gpu --build-arg TORCH_INDEX_URL=https://download.pytorch.org/whl/cu128 .
FROM python:3.11-slim-bookworm

ARG TORCH_VERSION=2.13.0
ARG TORCH_INDEX_URL=https://download.pytorch.org/whl/cpu
# Pinned so that a GPU build made on another day still matches the CPU image's Ray.
ARG RAY_VERSION=2.60.0

ENV PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1

# torch first, from the chosen index: resolved by the project's "torch>=2.4" alone, pip would pull
# the CUDA build from PyPI (gigabytes) even for CPU-only nodes.
RUN pip install "torch==${TORCH_VERSION}" --index-url "${TORCH_INDEX_URL}"

WORKDIR /opt/neuenh
COPY pyproject.toml README.md ./
COPY neuenh ./neuenh
COPY storage ./storage
COPY orchestrator ./orchestrator
COPY workers ./workers
COPY api ./api
COPY cli ./cli
# the shipped models (neuenh.pretrained: enhanced-ggx, ...), installed as the package's data
COPY models ./models
# the export extra: GET /v1/jobs/{id}/export writes ONNX (onnx) beside GLSL and the Mitsuba plugin
RUN pip install ".[export]" "ray==${RAY_VERSION}" "torch==${TORCH_VERSION}"

# Not root: the api's job store lives on a volume mounted at /var/lib/neuenh.
RUN useradd --create-home --uid 1000 neuenh \
    && mkdir -p /var/lib/neuenh \
    && chown neuenh:neuenh /var/lib/neuenh
USER neuenh
WORKDIR /home/neuenh

EXPOSE 8000 6379
CMD ["neuenh", "serve", "--host", "0.0.0.0", "--port", "8000", "--data-dir", "/var/lib/neuenh"]
