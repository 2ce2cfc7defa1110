# CANopen -> Modbus TCP / Zenoh edge gateway.
#
# Two stages: "build" makes a virtual environment in /opt/venv and installs the package into it
# (not editable); "runtime" copies only that venv onto a fresh base. BASE_IMAGE must be a Debian
# bookworm with python3 and its venv module: python:3.11-slim by default, or a local base built
# by deploy/container-test.sh where python is /usr/bin/python3. Both stages use the same base, so
# the venv's interpreter link points at the same python3 in both.
#
# Configuration: mount yours at /etc/canopen-gateway/config.yaml; without it the gateway exits 2
# with one line saying so (it never serves simulated values in its place). The demo (simulated
# devices, /etc/canopen-gateway/demo.yaml) runs only when asked for: `docker run IMAGE demo`, or
# CANOPEN_GATEWAY_DEMO=1. Any key can be overridden by an environment variable
# CANOPEN_GATEWAY__SECTION__KEY. The image turns on the health/metrics endpoint on 0.0.0.0:8080.
ARG BASE_IMAGE=python:3.11-slim

FROM ${BASE_IMAGE} AS build
ENV PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PYTHONDONTWRITEBYTECODE=1
RUN python3 -m venv /opt/venv
WORKDIR /src
# Dependencies first, read from pyproject.toml, so that a code change does not reinstall them.
# EXTRAS: optional dependency groups of pyproject.toml, comma separated (none by default;
# python-can-remote, for `can: {interface: remote}` and the demo's CAN bus server, is a main
# dependency).
ARG EXTRAS=
COPY pyproject.toml README.md ./
RUN /opt/venv/bin/python -c "import os, tomllib; \
p = tomllib.load(open('pyproject.toml', 'rb'))['project']; \
extras = [e.strip() for e in os.environ['EXTRAS'].split(',') if e.strip()]; \
print('\n'.join(p['dependencies'] + [r for e in extras for r in p['optional-dependencies'][e]]))" \
        > /tmp/requirements.txt \
    && /opt/venv/bin/pip install --requirement /tmp/requirements.txt
COPY canopen_gateway/ canopen_gateway/
RUN /opt/venv/bin/pip install --no-deps . \
    && /opt/venv/bin/pip uninstall --yes pip setuptools

FROM ${BASE_IMAGE} AS runtime
ARG BASE_IMAGE
ARG VERSION=0.1.0
ARG REVISION=unknown
LABEL org.opencontainers.image.title="canopen-gateway" \
      org.opencontainers.image.description="CANopen to Modbus TCP and Zenoh edge gateway" \
      org.opencontainers.image.version="${VERSION}" \
      org.opencontainers.image.revision="${REVISION}" \
      org.opencontainers.image.licenses="Apache-2.0" \
      org.opencontainers.image.base.name="${BASE_IMAGE}"
RUN useradd --uid 10001 --user-group --no-create-home --home-dir /nonexistent \
        --shell /usr/sbin/nologin gateway \
    && mkdir -p /var/lib/canopen-gateway/journal \
    && chown -R 10001:10001 /var/lib/canopen-gateway
COPY --from=build /opt/venv /opt/venv
COPY config/demo.yaml /etc/canopen-gateway/demo.yaml
COPY deploy/config/ /etc/canopen-gateway/
ENV PATH=/opt/venv/bin:$PATH \
    CANOPEN_GATEWAY_DEMO_CONFIG=/etc/canopen-gateway/demo.yaml \
    PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    CANOPEN_GATEWAY__HEALTH__HOST=0.0.0.0 \
    CANOPEN_GATEWAY__HEALTH__PORT=8080 \
    CANOPEN_GATEWAY__JOURNAL__PATH=/var/lib/canopen-gateway/journal
# The store and forward journal (docs/deploy.md): mount a volume here so that it outlives the
# container.
VOLUME ["/var/lib/canopen-gateway"]
# Numeric, so that Kubernetes' runAsNonRoot can verify it without reading /etc/passwd.
USER 10001:10001
WORKDIR /tmp
# Modbus TCP (502 needs CAP_NET_BIND_SERVICE; the demo uses 5020), Zenoh, health + metrics.
EXPOSE 502 5020 7447 8080
# The gateway handles SIGTERM itself (closes northbound servers, then the bus) within 2 s.
STOPSIGNAL SIGTERM
# /healthz over HTTP, or over HTTPS when the port answers no plain HTTP (health.tls: the
# container checks itself on loopback, so its own certificate is not verified).
HEALTHCHECK --interval=15s --timeout=3s --start-period=10s --retries=3 \
    CMD ["python3", "-c", "import os, ssl, urllib.error, urllib.request as u\nurl = '://127.0.0.1:%s/healthz' % os.environ.get('CANOPEN_GATEWAY__HEALTH__PORT', '8080')\ntry: u.urlopen('http' + url, timeout=2)\nexcept urllib.error.HTTPError: raise\nexcept OSError: c = ssl.create_default_context(); c.check_hostname = False; c.verify_mode = ssl.CERT_NONE; u.urlopen('https' + url, timeout=2, context=c)"]
ENTRYPOINT ["canopen-gateway"]
CMD ["run", "-c", "/etc/canopen-gateway/config.yaml"]
