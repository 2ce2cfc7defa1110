#!/usr/bin/env bash
# Builds the gateway container image with podman and checks it live.
#
#   bash deploy/container-test.sh               # everything below
#   bash deploy/container-test.sh --build-only  # steps 1-3 only
#
# 1. Installs podman, buildah, runc and debootstrap with apt when missing (one apt-get update).
# 2. Builds the local base image localhost/bookworm-py:latest when missing: no registry of images
#    is reachable here, so a Debian bookworm rootfs is made with debootstrap and cached as a
#    tarball in $BASE_CACHE (outside the repository) for the next run.
# 3. Builds the gateway image from the Dockerfile on that base.
# 4. Runs the image's own command without a config mounted and expects exit code 2 with one
#    line naming /etc/canopen-gateway/config.yaml and saying to mount one (it never serves the
#    demo in its place). Then runs the demo, asked for (`demo` command), with host networking,
#    a read-only root file system and a named
#    volume at /var/lib/canopen-gateway (as compose does); waits (bounded) for /healthz to answer
#    200; runs the image's own HEALTHCHECK; scrapes /metrics and expects received CAN frames
#    counted; reads a position input register twice over Modbus TCP and expects a change;
#    subscribes with a Zenoh peer and expects samples; expects /healthz to show the journal
#    (journal.path, set by the image) writing into the volume; stops the container with SIGTERM
#    and expects it gone within 2 s.
# 5. Starts a new container on the same volume, the demo asked for by CANOPEN_GATEWAY_DEMO=1 this
#    time, and expects the journal kept: /healthz shows it again and a Zenoh `_time` query
#    answers the state events journaled before the first stop.
#    The containers and the volume are removed whatever happens.
#
# Idempotent: every step skips what is already there. Needs root (apt, rootful podman). Exits
# non-zero with a "FAIL:" line on the first failed check. Ports 5020 (Modbus), 7447 (Zenoh) and
# 8080 (health) are used when free; when another process holds one, a free port is taken instead
# and handed to the gateway through CANOPEN_GATEWAY__* environment overrides.
set -euo pipefail

cd "$(dirname "$0")/.."
ROOT=$PWD

IMAGE=${IMAGE:-localhost/canopen-gateway:test}
BASE_IMAGE=${BASE_IMAGE:-localhost/bookworm-py:latest}
BASE_CACHE=${BASE_CACHE:-/var/tmp/canopen-gateway-base}
PY=${PY:-$ROOT/.venv/bin/python}
CLI=${CLI:-$ROOT/.venv/bin/canopen-gateway}
CONFIG=config/demo.yaml  # the image's demo (/etc/canopen-gateway/demo.yaml), run when asked for
IMAGE_CONFIG=/etc/canopen-gateway/config.yaml  # where a plant's config is mounted
CONTAINER=canopen-gateway-test-$$
VOLUME=canopen-gateway-test-journal-$$  # the journal's volume, kept across both containers
STATE_DIR=/var/lib/canopen-gateway       # the image's VOLUME
JOURNAL_DIR=$STATE_DIR/journal           # journal.path, set by the image
HISTORY_KEY='canopen/demo/*/state'       # the demo config's gateway.name is demo
HEALTH_TIMEOUT_S=${HEALTH_TIMEOUT_S:-60}
STOP_LIMIT_S=2
# The vfs storage driver and runc work where overlayfs and crun do not (crun fails on
# cgroup setups of nested containers and CI machines).
PODMAN=(podman --storage-driver vfs --runtime runc)

BUILD_ONLY=0
case "${1:-}" in
  --build-only) BUILD_ONLY=1 ;;
  "") ;;
  *) echo "usage: $0 [--build-only]" >&2; exit 2 ;;
esac

step() { printf '\n==> %s\n' "$*"; }
fail() { printf '\nFAIL: %s\n' "$*" >&2; exit 1; }

[[ $(id -u) -eq 0 ]] || fail "run as root (apt-get and rootful podman are needed)"

# --- 1. tools -----------------------------------------------------------------------------------
ensure_tools() {
  local missing=() tool
  for tool in podman buildah runc debootstrap; do
    command -v "$tool" >/dev/null 2>&1 || missing+=("$tool")
  done
  if ((${#missing[@]})); then
    step "installing ${missing[*]} with apt"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq || fail "apt-get update failed"
    apt-get install -y -qq "${missing[@]}" >/dev/null || fail "apt-get install ${missing[*]} failed"
  fi
}

# --- 2. local base image ------------------------------------------------------------------------
# Bump BASE_RECIPE when the recipe below changes: an image from an older recipe is rebuilt.
BASE_RECIPE=2
ensure_base() {
  local have
  have=$("${PODMAN[@]}" image inspect --format '{{index .Labels "base-recipe"}}' "$BASE_IMAGE" \
    2>/dev/null || true)
  if [[ $have == "$BASE_RECIPE" ]]; then
    return
  fi
  local tarball=$BASE_CACHE/bookworm-py-r$BASE_RECIPE.tar
  if [[ ! -s $tarball ]]; then
    step "debootstrap bookworm with python3 into $BASE_CACHE (about a minute)"
    mkdir -p "$BASE_CACHE"
    local rootfs=$BASE_CACHE/rootfs.partial
    rm -rf "$rootfs"
    # No python3-pip in the rootfs: the image's venv brings its own pip (ensurepip).
    debootstrap --variant=minbase --include=python3,python3-venv,ca-certificates \
      bookworm "$rootfs" >"$BASE_CACHE/debootstrap.log" 2>&1 \
      || fail "debootstrap failed, see $BASE_CACHE/debootstrap.log"
    # Slim it like python:3.11-slim: no package caches, manuals, translations or docs (the
    # copyright files stay).
    rm -rf "$rootfs"/var/cache/apt/* "$rootfs"/var/lib/apt/lists/* "$rootfs"/usr/share/man/* \
      "$rootfs"/usr/share/locale/* "$rootfs"/usr/share/info/*
    find "$rootfs"/usr/share/doc -type f ! -name copyright -delete
    tar -C "$rootfs" -cf "$tarball.partial" . && mv "$tarball.partial" "$tarball"
    rm -rf "$rootfs"
  fi
  step "importing $tarball as $BASE_IMAGE"
  "${PODMAN[@]}" import --change "LABEL base-recipe=$BASE_RECIPE" "$tarball" "$BASE_IMAGE" \
    >/dev/null || fail "podman import failed"
}

# --- 3. gateway image ---------------------------------------------------------------------------
build_image() {
  step "building $IMAGE on $BASE_IMAGE"
  local revision
  revision=$(git -C "$ROOT" rev-parse --short HEAD 2>/dev/null || echo unknown)
  # --format docker keeps HEALTHCHECK (the OCI image format has no field for it).
  # pip inside the build needs a CA bundle to reach PyPI: the host's, mounted read-only.
  "${PODMAN[@]}" build --isolation chroot --format docker \
    -v /etc/ssl/certs/ca-certificates.crt:/etc/ssl/certs/ca-certificates.crt:ro \
    --build-arg BASE_IMAGE="$BASE_IMAGE" --build-arg REVISION="$revision" \
    -t "$IMAGE" "$ROOT" || fail "image build failed"
  local size_b
  size_b=$("${PODMAN[@]}" image inspect --format '{{.Size}}' "$IMAGE")
  printf 'image %s: %s MB\n' "$IMAGE" "$((size_b / 1000000))"
}

ensure_tools
ensure_base
build_image
if ((BUILD_ONLY)); then
  echo "build only: done"
  exit 0
fi

# --- 4. live checks -----------------------------------------------------------------------------
[[ -x $PY ]] || fail "$PY missing: run 'make container-test' (it installs .venv first)"
[[ -x $CLI ]] || fail "$CLI missing: install the package into .venv"

cleanup() {
  if "${PODMAN[@]}" container exists "$CONTAINER" 2>/dev/null; then
    "${PODMAN[@]}" rm -f -t 0 "$CONTAINER" >/dev/null 2>&1 || true
  fi
  if "${PODMAN[@]}" volume exists "$VOLUME" 2>/dev/null; then
    "${PODMAN[@]}" volume rm -f "$VOLUME" >/dev/null 2>&1 || true
  fi
  rm -rf "${LOGDIR:-}"
}
trap cleanup EXIT

show_logs_and_fail() {
  echo "--- container logs (last 40 lines) ---" >&2
  "${PODMAN[@]}" logs --tail 40 "$CONTAINER" >&2 2>&1 || true
  fail "$*"
}

port_or_free() {  # the preferred port when nothing listens on it, else a free ephemeral port
  "$PY" "$ROOT/deploy/livecheck.py" free-port "$1"
}
MODBUS_PORT=$(port_or_free 5020)
ZENOH_PORT=$(port_or_free 7447)
HEALTH_PORT=$(port_or_free 8080)
ZENOH_ENDPOINT=tcp/127.0.0.1:$ZENOH_PORT
echo "ports: modbus $MODBUS_PORT, zenoh $ZENOH_PORT, health $HEALTH_PORT"

step "finding a position input register in '$CLI registers -c $CONFIG --csv'"
REGISTER=$("$CLI" registers -c "$CONFIG" --csv | "$PY" "$ROOT/deploy/livecheck.py" pick-register) \
  || fail "no position input register in the register table of $CONFIG"
echo "register: $REGISTER"

# Podman logs "unable to get systemd connection" for HEALTHCHECK timers on machines without
# systemd; the check is run by hand below, so those lines are dropped.
quiet_podman() {
  local err=$LOGDIR/podman.err rc=0
  "${PODMAN[@]}" "$@" 2>"$err" || rc=$?
  grep -v 'systemd connection' "$err" >&2 || true
  return "$rc"
}
LOGDIR=$(mktemp -d)

# The named volume is created by the first run from the image's content there (owned by 10001).
# start_container [ENV=VALUE...] [-- COMMAND...]: the demo asked for by the command or the env.
start_container() {
  local envs=() cmd=()
  while (($#)); do
    if [[ $1 == -- ]]; then shift; cmd=("$@"); break; fi
    envs+=(-e "$1"); shift
  done
  quiet_podman run -d --name "$CONTAINER" --network host --read-only \
    -v "$VOLUME:$STATE_DIR" \
    --ulimit nofile=20000:20000 --ulimit nproc=4096:4096 \
    -e CANOPEN_GATEWAY__HEALTH__HOST=127.0.0.1 \
    -e CANOPEN_GATEWAY__HEALTH__PORT="$HEALTH_PORT" \
    -e CANOPEN_GATEWAY__MODBUS__PORT="$MODBUS_PORT" \
    -e CANOPEN_GATEWAY__ZENOH__LISTEN="[\"$ZENOH_ENDPOINT\"]" \
    "${envs[@]}" "$IMAGE" "${cmd[@]}" >/dev/null || fail "podman run failed"
}

wait_ready() {
  step "waiting up to ${HEALTH_TIMEOUT_S}s for http://127.0.0.1:$HEALTH_PORT/healthz to answer 200"
  local deadline=$((SECONDS + HEALTH_TIMEOUT_S))
  until "$PY" "$ROOT/deploy/livecheck.py" wait-healthy "http://127.0.0.1:$HEALTH_PORT/healthz" 2 \
    >"$LOGDIR/health.out"; do
    [[ $("${PODMAN[@]}" inspect --format '{{.State.Running}}' "$CONTAINER") == true ]] \
      || show_logs_and_fail "the container exited before it became ready"
    ((SECONDS < deadline)) || { cat "$LOGDIR/health.out"; show_logs_and_fail "not ready in time"; }
  done
  cat "$LOGDIR/health.out"
}

check_journal() {
  step "/healthz shows the journal in $JOURNAL_DIR (volume $VOLUME) writing"
  "$PY" "$ROOT/deploy/livecheck.py" journal "http://127.0.0.1:$HEALTH_PORT/healthz" "$JOURNAL_DIR" \
    || show_logs_and_fail "no journal writing in $JOURNAL_DIR"
}

step "the image's own command without a config mounted: exit 2, one line saying to mount one"
rc=0
"${PODMAN[@]}" run --rm --network host --read-only --ulimit nofile=20000:20000 \
  --ulimit nproc=4096:4096 "$IMAGE" >"$LOGDIR/noconfig.out" 2>"$LOGDIR/noconfig.err" || rc=$?
grep -v 'systemd connection' "$LOGDIR/noconfig.err" >"$LOGDIR/noconfig.lines" || true
cat "$LOGDIR/noconfig.lines"
[[ $rc -eq 2 ]] || fail "the image without a config exited $rc (expected 2)"
[[ $(wc -l <"$LOGDIR/noconfig.lines") -eq 1 && ! -s $LOGDIR/noconfig.out ]] \
  || fail "the image without a config did not say it in one line"
grep -q "$IMAGE_CONFIG.*mount" "$LOGDIR/noconfig.lines" \
  || fail "the line does not name $IMAGE_CONFIG and say to mount one"

step "starting $CONTAINER (the demo asked for: command demo; read-only, volume $VOLUME)"
start_container -- demo
wait_ready

step "running the image's HEALTHCHECK"
"${PODMAN[@]}" image inspect --format '{{json .Config.Healthcheck}}' "$IMAGE" | grep -q healthz \
  || fail "the image has no HEALTHCHECK (built without --format docker?)"
quiet_podman healthcheck run "$CONTAINER" || show_logs_and_fail "HEALTHCHECK reports unhealthy"
echo "healthy"

step "scraping http://127.0.0.1:$HEALTH_PORT/metrics"
"$PY" "$ROOT/deploy/livecheck.py" metrics "http://127.0.0.1:$HEALTH_PORT/metrics" \
  || show_logs_and_fail "/metrics has no received frames"

step "reading input register $REGISTER over Modbus TCP on 127.0.0.1:$MODBUS_PORT"
"$PY" "$ROOT/deploy/livecheck.py" modbus-changes 127.0.0.1 "$MODBUS_PORT" "$REGISTER" \
  || show_logs_and_fail "Modbus check failed"

step "subscribing with a Zenoh peer connected to $ZENOH_ENDPOINT"
"$PY" "$ROOT/deploy/livecheck.py" zenoh-samples "$ZENOH_ENDPOINT" \
  || show_logs_and_fail "Zenoh check failed"

check_journal
# The journal's entries up to now: the next container must still answer them.
BEFORE_STOP=$(date -u +%Y-%m-%dT%H:%M:%SZ)

step "podman stop -t 10 (SIGTERM), expecting exit within ${STOP_LIMIT_S}s"
t0=$(date +%s.%N)
quiet_podman stop -t 10 "$CONTAINER" >/dev/null || fail "podman stop failed"
t1=$(date +%s.%N)
exit_code=$("${PODMAN[@]}" inspect --format '{{.State.ExitCode}}' "$CONTAINER")
elapsed_s=$("$PY" -c "print(f'{$t1 - $t0:.2f}')")
echo "stopped in ${elapsed_s}s, exit code $exit_code"
"$PY" -c "import sys; sys.exit(0 if $t1 - $t0 < $STOP_LIMIT_S else 1)" \
  || show_logs_and_fail "SIGTERM took ${elapsed_s}s (limit ${STOP_LIMIT_S}s)"
[[ $exit_code == 0 || $exit_code == 143 ]] \
  || show_logs_and_fail "exit code $exit_code after SIGTERM (expected 0)"

# --- 5. the journal outlives the container -----------------------------------------------------
step "the volume $VOLUME holds the journal"
mountpoint=$("${PODMAN[@]}" volume inspect --format '{{.Mountpoint}}' "$VOLUME")
stat -c '%u:%g %a %n' "$mountpoint" "$mountpoint/journal" "$mountpoint/journal/journal.sqlite3" \
  || fail "no journal.sqlite3 in the volume $VOLUME ($mountpoint)"

step "a new container on the same volume (the demo asked for: CANOPEN_GATEWAY_DEMO=1)"
quiet_podman rm "$CONTAINER" >/dev/null || fail "podman rm failed"
start_container CANOPEN_GATEWAY_DEMO=1
wait_ready
check_journal

step "the journal kept what it had: get $HISTORY_KEY?_time=[..$BEFORE_STOP]"
"$PY" "$ROOT/deploy/livecheck.py" history "$ZENOH_ENDPOINT" "$HISTORY_KEY" "$BEFORE_STOP" \
  || show_logs_and_fail "the new container answers no history from before the first one stopped"

cleanup
echo
echo "container-test: all checks passed (image $IMAGE)"
