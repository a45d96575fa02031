# One image for the API and the workers: `weldpool serve --no-worker` or `weldpool worker`.
FROM python:3.11-slim

# CPU wheels by default; build with --build-arg TORCH_INDEX=https://download.pytorch.org/whl/cu128
# (and a matching torch pin in constraints.txt) for a CUDA worker image.
ARG TORCH_INDEX=https://download.pytorch.org/whl/cpu
ENV PIP_NO_CACHE_DIR=1 PYTHONUNBUFFERED=1 WELDPOOL_HOME=/data

RUN apt-get update && apt-get install -y --no-install-recommends libgl1 libglib2.0-0 \
    && rm -rf /var/lib/apt/lists/*
WORKDIR /opt/weldpool
COPY . .
RUN pip install --extra-index-url "$TORCH_INDEX" -c constraints.txt -e .
VOLUME /data
EXPOSE 8000
CMD ["weldpool", "serve", "--host", "0.0.0.0", "--no-worker"]
