# behave in a container: the CPU-only torch build and the package without extras (what running needs).
#   docker build -t behave .
#   docker run --rm -v "$PWD/runs:/work/runs" behave populate --duration 60
FROM python:3.12-slim
WORKDIR /opt/behave
COPY pyproject.toml constraints.txt README.md ./
COPY behaviors ./behaviors
COPY cli ./cli
COPY sumo_scenarios ./sumo_scenarios
# torch from PyTorch's CPU index first (PyPI's torch is the CUDA build, several GB more), then the rest
RUN pip install --no-cache-dir --disable-pip-version-check torch==2.13.0 \
        --index-url https://download.pytorch.org/whl/cpu \
    && pip install --no-cache-dir --disable-pip-version-check -c constraints.txt .
WORKDIR /work
ENTRYPOINT ["behave"]
CMD ["populate", "--duration", "60"]
