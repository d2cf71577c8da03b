# The service only: FastAPI + onnxruntime + the default model. No torch, gmsh, scikit-fem or FE code.
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 PIP_DISABLE_PIP_VERSION_CHECK=1
WORKDIR /app

# Dependencies in their own layer, read from pyproject's `service` extra (one list to keep up to date).
COPY pyproject.toml .
RUN python3 -c "import tomllib; p = tomllib.load(open('pyproject.toml', 'rb'))['project']; \
print('\n'.join(p['dependencies'] + p['optional-dependencies']['service']))" > requirements.txt \
 && python3 -m venv /opt/venv \
 && /opt/venv/bin/python -m pip install --no-cache-dir -r requirements.txt

COPY contracts/ contracts/
# service/ carries the viewer's page and its vendored three.js (service/static/viewer): no npm, no CDN
COPY service/ service/
COPY models/default/ models/default/

RUN useradd --uid 10001 --no-create-home --shell /usr/sbin/nologin deform
USER deform

ENV PATH=/opt/venv/bin:$PATH DEFORM_HOST=0.0.0.0 DEFORM_PORT=8000 DEFORM_MODEL=/app/models/default
# 18944: OpenIGTLink, served only with DEFORM_IGTL=true
EXPOSE 8000 18944
# Every DEFORM_* variable given to `docker run -e` / `podman run -e` reaches the service's settings; the
# health check reads the same settings (port, TLS).
HEALTHCHECK --interval=10s --timeout=3s --start-period=15s --retries=3 \
  CMD ["python", "-m", "service.healthcheck"]
CMD ["python", "-m", "service"]
