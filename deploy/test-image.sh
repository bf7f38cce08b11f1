#!/usr/bin/env bash
# Build the image with deploy/build-image.sh and run it with podman on loopback: robot-server in
# the container must answer PING and pass `simple-message conformance server` from this machine,
# its health check must say healthy, and it must stop on SIGTERM with exit status 0. Then the same
# for a cell of deploy/kubernetes/ (the StatefulSet's command, fleet file and probe, run as the pod
# would be) and for the cell of deploy/compose.yaml (when podman-compose is installed).
#
# Needs podman (apt-get install podman mmdebstrap uidmap), the project installed here (robot-client
# and simple-message on PATH: the clients) and Python >= 3.11. .ci/run runs it; so does
# tests/test_deploy.py's slow test.
#
# Exit status: 0 passed, 1 failed, 77 skipped (podman or the clients missing: the reason on stderr).
#
# podman is told, by a containers.conf this script writes (CONTAINERS_CONF), to use runc and
# cgroupfs and to set explicit limits on open files and processes: a sandbox without
# CAP_SYS_RESOURCE cannot raise them to the runtime's defaults, and one with a hybrid cgroup
# hierarchy has no systemd to manage cgroups. That is this machine's business, not the image's.
set -euo pipefail

here=$(cd "$(dirname "$0")" && pwd)
PYTHON=${PYTHON:-python3}
run_id="sm-image-test-$$"
passed=0
failed=0

skip() {
    echo "test-image.sh: SKIPPED: $*" >&2
    exit 77
}
command -v podman >/dev/null 2>&1 || skip "podman is not installed (apt-get install podman mmdebstrap uidmap)"
for tool in robot-client simple-message; do
    command -v "$tool" >/dev/null 2>&1 || skip "$tool is not on PATH (pip install -e . first)"
done

work=$(mktemp -d)
containers=()
compose=()
cleanup() {
    if [ "${#compose[@]}" -gt 0 ]; then
        "${compose[@]}" down >/dev/null 2>&1 || true
    fi
    for c in "${containers[@]}"; do
        podman rm -f -t 5 "$c" >/dev/null 2>&1 || true
    done
    # podman-compose leaves the project's network behind
    podman network rm -f "${run_id}_default" >/dev/null 2>&1 || true
    rm -rf "$work"
}
trap cleanup EXIT

# this machine's podman settings (see the header)
hard() { # hard FLAG CAP: the hard limit of ulimit -FLAG, at most CAP
    local v
    v=$(ulimit -H "-$1")
    if [ "$v" = unlimited ] || [ "$v" -gt "$2" ]; then v=$2; fi
    echo "$v"
}
nofile=$(hard n 65536)
nproc=$(hard u 4096)
{
    echo "[containers]"
    echo "default_ulimits = [\"nofile=$nofile:$nofile\", \"nproc=$nproc:$nproc\"]"
    echo "[engine]"
    echo 'cgroup_manager = "cgroupfs"'
    if command -v runc >/dev/null 2>&1; then echo 'runtime = "runc"'; fi
} >"$work/containers.conf"
export CONTAINERS_CONF="$work/containers.conf"

ok() {
    passed=$((passed + 1))
    echo "PASS  $*"
}
bad() {
    failed=$((failed + 1))
    echo "FAIL  $*"
}
check() { # check WHAT COMMAND...: PASS when COMMAND exits 0; FAIL shows the end of its output
    local what=$1
    shift
    if "$@" >"$work/out" 2>&1; then ok "$what"; else
        bad "$what"
        tail -n 20 "$work/out" | sed 's/^/      /'
    fi
    cat "$work/out" >>"$work/log"
}

free_ports() { # free_ports N: N TCP ports free on 127.0.0.1 now
    "$PYTHON" - "$1" <<'EOF'
import socket, sys
socks = [socket.socket() for _ in range(int(sys.argv[1]))]
for s in socks:
    s.bind(("127.0.0.1", 0))
print(" ".join(str(s.getsockname()[1]) for s in socks))
EOF
}

wait_ready() { # wait_ready CONTAINER [LINE]: until robot-server printed its ready line, at most 60 s
    local line=${2:-robot-server ready}
    for _ in $(seq 240); do
        if podman logs "$1" 2>/dev/null | grep -q "$line"; then return 0; fi
        if [ "$(podman inspect --format '{{.State.Running}}' "$1" 2>/dev/null)" != true ]; then break; fi
        sleep 0.25
    done
    echo "$1 did not become ready:" >&2
    podman logs "$1" >&2 || true
    return 1
}

web_page() { # web_page URL: the page answers 200
    "$PYTHON" - "$1" <<'EOF'
import sys, urllib.request
try:
    status = urllib.request.urlopen(sys.argv[1], timeout=10).status
except OSError as exc:  # URLError and HTTPError are OSErrors
    sys.exit(f"GET {sys.argv[1]}: {exc}")
sys.exit(0 if status == 200 else f"GET {sys.argv[1]}: status {status}")
EOF
}

stops_cleanly() { # stops_cleanly CONTAINER: SIGTERM, then exit status 0 (robot-server brings the robot to rest)
    podman stop -t 20 "$1" >/dev/null && [ "$(podman inspect --format '{{.State.ExitCode}}' "$1")" = 0 ]
}

echo "== build"
start=$(date +%s)
if ! tag=$("$here/build-image.sh" 2>"$work/build.log" | tail -n 1); then
    tail -n 40 "$work/build.log" >&2
    echo "image: 0 passed, 1 failed"
    exit 1
fi
size=$(podman image inspect --format '{{.Size}}' "$tag")
echo "built $tag in $(($(date +%s) - start)) s, $((size / 1000000)) MB"

echo "== one controller, the image's default command (generic profile)"
read -r motion state <<<"$(free_ports 2)"
generic="$run_id-generic"
containers+=("$generic")
# (podman's complaint that no systemd runs the health check's timer goes to the log: the checks
# below run it with podman healthcheck run)
podman run -d --name "$generic" -p "127.0.0.1:$motion:11000" -p "127.0.0.1:$state:11002" "$tag" \
    >/dev/null 2>>"$work/log"
if wait_ready "$generic"; then
    ok "robot-server started in the container: $(podman logs "$generic" 2>/dev/null | grep 'robot-server ready')"
    check "PING from this machine (127.0.0.1:$motion)" \
        robot-client ping --host 127.0.0.1 --motion-port "$motion" --state-port "$state" --count 3
    check "simple-message conformance server --allow-motion" \
        simple-message conformance server --motion-port "$motion" --state-port "$state" --allow-motion 127.0.0.1
    check "health check (a PING inside the container)" podman healthcheck run "$generic"
    check "SIGTERM: exit status 0" stops_cleanly "$generic"
else
    bad "robot-server did not start in the container"
fi

echo "== another command: MotoROS with its IO port and the web view"
read -r motion state io web <<<"$(free_ports 4)"
moto="$run_id-motoros"
containers+=("$moto")
podman run -d --name "$moto" -p "127.0.0.1:$motion:50240" -p "127.0.0.1:$state:50241" -p "127.0.0.1:$io:50242" \
    -p "127.0.0.1:$web:8080" "$tag" --profile motoros --host 0.0.0.0 --web 0.0.0.0:8080 >/dev/null 2>>"$work/log"
if wait_ready "$moto"; then
    ok "robot-server --profile motoros started in the container"
    check "PING from this machine (127.0.0.1:$motion)" robot-client ping --profile motoros \
        --host 127.0.0.1 --motion-port "$motion" --state-port "$state" --count 3
    check "simple-message conformance server --profile motoros" simple-message conformance server \
        --profile motoros --motion-port "$motion" --state-port "$state" --io-port "$io" 127.0.0.1
    check "health check follows the command (MotoROS's ports)" podman healthcheck run "$moto"
    check "web view answers on 127.0.0.1:$web" web_page "http://127.0.0.1:$web/"
    check "SIGTERM: exit status 0" stops_cleanly "$moto"
else
    bad "robot-server --profile motoros did not start in the container"
fi

echo "== a cell of deploy/kubernetes/ under podman: the StatefulSet's command, fleet file and probe"
# the pod as the manifests describe it (read-only root, no capabilities, user 10001), on a loopback
# address of its own: what a cluster would run, short of the cluster
if ! "$PYTHON" -c "import yaml" 2>/dev/null; then
    echo "skipped: PyYAML is not installed here (pip install -e '.[dev]' brings it)"
else
    "$PYTHON" - "$here/kubernetes" "$work" <<'EOF'
import sys, tomllib
from pathlib import Path
import yaml
manifests, work = Path(sys.argv[1]), Path(sys.argv[2])
docs = [d for f in sorted(manifests.glob("*.yaml")) for d in yaml.safe_load_all(f.read_text()) if d]
(config,) = [d for d in docs if d["kind"] == "ConfigMap"]
(sts,) = [d for d in docs if d["kind"] == "StatefulSet"]
(container,) = sts["spec"]["template"]["spec"]["containers"]
fleet = config["data"]["fleet.toml"]
(work / "fleet.toml").write_text(fleet)
(work / "args").write_text("\n".join(container["args"]) + "\n")
(work / "probe").write_text("\n".join(container["livenessProbe"]["exec"]["command"]) + "\n")
(work / "ports").write_text("\n".join(str(p["containerPort"]) for p in container["ports"]) + "\n")
data = tomllib.loads(fleet)
lines = []
for table in data["controller"]:
    c = {**data.get("defaults", {}), **table}
    ports = [str(c[k]) for k in ("motion_port", "state_port", "io_port") if k in c]
    lines.append(" ".join([c["name"], c.get("profile", "generic"), *ports]))
(work / "controllers").write_text("\n".join(lines) + "\n")
EOF
    chmod a+r "$work/fleet.toml"
    cell=127.0.0.39
    pod="$run_id-cell"
    containers+=("$pod")
    publish=()
    while read -r port; do publish+=(-p "$cell:$port:$port"); done <"$work/ports"
    mapfile -t args <"$work/args"
    mapfile -t probe <"$work/probe"
    podman run -d --name "$pod" --read-only --cap-drop=ALL --security-opt=no-new-privileges --user 10001:10001 \
        -v "$work/fleet.toml:/etc/robot-server/fleet.toml:ro" "${publish[@]}" "$tag" "${args[@]}" \
        >/dev/null 2>>"$work/log"
    if wait_ready "$pod" "robot-server fleet ready"; then
        ok "robot-server ${args[*]}: $(podman logs "$pod" 2>/dev/null | grep 'fleet ready')"
        check "the StatefulSet's probe: ${probe[*]}" podman exec "$pod" "${probe[@]}"
        while read -r name profile motion state io; do
            io_opt=()
            if [ -n "$io" ]; then io_opt=(--io-port "$io"); fi
            check "$name ($profile): conformance on $cell:$motion" simple-message conformance server \
                --profile "$profile" --motion-port "$motion" --state-port "$state" "${io_opt[@]}" "$cell"
            check "$name: its web view at /c/$name/" web_page "http://$cell:8080/c/$name/"
        done <"$work/controllers"
        check "the fleet's web view: the index at /" web_page "http://$cell:8080/"
        check "SIGTERM: exit status 0" stops_cleanly "$pod"
    else
        bad "robot-server ${args[*]} did not start in the container"
    fi
fi

echo "== the cell of deploy/compose.yaml"
if podman compose version >/dev/null 2>&1; then
    compose=(podman compose)
elif command -v podman-compose >/dev/null 2>&1; then
    compose=(podman-compose)
fi
if [ "${#compose[@]}" = 0 ]; then
    echo "skipped: neither 'podman compose' nor podman-compose is installed (apt-get install podman-compose)"
else
    # a loopback address of its own, so that the vendors' ports cannot meet a server on 127.0.0.1
    cell=127.0.0.38
    export CELL_ADDRESS=$cell VERSION=${tag##*:}
    name="${compose[*]}"
    compose+=(-f "$here/compose.yaml" -p "$run_id")
    if "${compose[@]}" up -d >>"$work/log" 2>&1; then
        compose_up_ok=1
    else
        compose_up_ok=0
        tail -n 30 "$work/log" | sed 's/^/      /'
    fi
    moto_c=$(podman ps -a --filter "name=$run_id.motoman" --format '{{.Names}}')
    abb_c=$(podman ps -a --filter "name=$run_id.abb" --format '{{.Names}}')
    if [ "$compose_up_ok" = 1 ] && [ -n "$moto_c" ] && [ -n "$abb_c" ] && wait_ready "$moto_c" && wait_ready "$abb_c"; then
        ok "$name up: the cell's two controllers started ($moto_c, $abb_c)"
        check "MotoROS arm: conformance on $cell:50240" simple-message conformance server --profile motoros $cell
        check "ABB arm: conformance on $cell:11000" simple-message conformance server --profile abb $cell
        check "MotoROS arm: health check" podman healthcheck run "$moto_c"
        check "ABB arm: health check (ports listening, nothing sent)" podman healthcheck run "$abb_c"
        check "MotoROS arm: web view on $cell:8080" web_page "http://$cell:8080/"
        check "ABB arm: web view on $cell:8081" web_page "http://$cell:8081/"
    else
        bad "$name up: the cell did not start"
    fi
    check "$name down" "${compose[@]}" down
    compose=()
fi

echo "image: $passed passed, $failed failed"
[ "$failed" = 0 ]
