"""deploy/: the image, the compose cell and the Kubernetes manifests agree with each other and with
the project, offline; the image itself is built and run by deploy/test-image.sh (the slow test).

The manifests are validated against the API schemas of named Kubernetes versions
(``kubernetes-validate``); the fleet file of their ConfigMap must be one robot-server reads, and
every port a controller of it serves must be the one its Services, the StatefulSet's container
ports and the NetworkPolicy name, so that the files cannot drift apart.
"""

from __future__ import annotations

import importlib.util
import os
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest
import yaml

from robot_server.emulator import Emulator, EmulatorConfig
from robot_server.fleet.config import load_fleet
from simple_message import LE32
from simple_message.dialects import dialect

ROOT = Path(__file__).resolve().parent.parent
DEPLOY = ROOT / "deploy"
#: the Kubernetes versions whose API schemas the manifests must satisfy (strictly: no unknown field)
KUBERNETES_VERSIONS = ("1.28.0", "1.33.0")
#: where the StatefulSet mounts the ConfigMap, and the key of the fleet file in it
FLEET_DIR, FLEET_KEY = "/etc/robot-server", "fleet.toml"
WEB_PORT = 8080


def version() -> str:
    return str(tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"])


def manifests() -> list[tuple[Path, dict[str, Any]]]:
    docs = []
    for path in sorted((DEPLOY / "kubernetes").glob("*.yaml")):
        docs += [(path, doc) for doc in yaml.safe_load_all(path.read_text()) if doc]
    return docs


def resource(kind: str, name: str | None = None) -> dict[str, Any]:
    found = [d for _, d in manifests() if d["kind"] == kind and name in (None, d["metadata"]["name"])]
    assert len(found) == 1, f"{len(found)} {kind} {name or ''} in deploy/kubernetes"
    return found[0]


def container() -> dict[str, Any]:
    (only,) = resource("StatefulSet")["spec"]["template"]["spec"]["containers"]
    return only


def fleet() -> dict[str, Any]:
    return tomllib.loads(resource("ConfigMap")["data"][FLEET_KEY])


def served_ports(config: EmulatorConfig) -> dict[str, int]:
    """The ports robot-server binds for one controller, by role: the file's, else its profile's."""
    ports = {role: config.port(role) for role in ("motion", "state", "io")}
    return {role: port for role, port in ports.items() if port is not None}


def fleet_ports(tmp_path: Path) -> dict[str, dict[str, int]]:
    """Each controller of the ConfigMap's fleet file and its ports, as robot-server reads the file."""
    path = tmp_path / FLEET_KEY
    path.write_text(resource("ConfigMap")["data"][FLEET_KEY])
    return {c.name: served_ports(c.config) for c in load_fleet(path, check_ports=False).controllers}


def healthcheck() -> ModuleType:
    spec = importlib.util.spec_from_file_location("deploy_healthcheck", DEPLOY / "healthcheck.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


# -- the Kubernetes manifests ------------------------------------------------------------------------


@pytest.mark.parametrize("kubernetes", KUBERNETES_VERSIONS)
def test_every_manifest_validates_against_the_api_schemas(kubernetes: str) -> None:
    import kubernetes_validate

    docs = manifests()
    assert {d["kind"] for _, d in docs} >= {"StatefulSet", "ConfigMap", "Service", "NetworkPolicy"}
    for path, doc in docs:
        try:
            kubernetes_validate.validate(doc, kubernetes, strict=True)
        except kubernetes_validate.ValidationError as exc:
            pytest.fail(f"{path.name}: {doc['kind']} {doc['metadata']['name']}: {exc.message} at {list(exc.path)}")


def test_the_fleet_file_is_one_robot_server_reads(tmp_path: Path) -> None:
    path = tmp_path / FLEET_KEY
    path.write_text(resource("ConfigMap")["data"][FLEET_KEY])
    spec = load_fleet(path, check_ports=False)
    assert [c.name for c in spec.controllers] == [t["name"] for t in fleet()["controller"]]
    assert fleet()["defaults"]["host"] == "0.0.0.0"  # reachable through the pod's address


def test_the_statefulset_runs_the_configmaps_fleet_with_its_web_view_and_probes() -> None:
    sts = resource("StatefulSet")
    pod = sts["spec"]["template"]["spec"]
    c = container()
    assert sts["spec"]["serviceName"] == "robot-cell" == resource("Service", "robot-cell")["metadata"]["name"]
    assert c["image"] == f"simple-message-stack:{version()}"
    fleet_file = f"{FLEET_DIR}/{FLEET_KEY}"
    assert c["args"] == ["--fleet", fleet_file, "--web", f"0.0.0.0:{WEB_PORT}"]
    (mount,) = [m for m in c["volumeMounts"] if m["mountPath"] == FLEET_DIR]
    (volume,) = [v for v in pod["volumes"] if v["name"] == mount["name"]]
    assert volume["configMap"]["name"] == resource("ConfigMap")["metadata"]["name"]
    for probe in ("startupProbe", "readinessProbe", "livenessProbe"):
        assert c[probe]["exec"]["command"] == ["robot-server-healthcheck", "--fleet", fleet_file]
    # the image's user, and nothing more than a simple_message server needs
    assert pod["securityContext"]["runAsNonRoot"] and pod["securityContext"]["runAsUser"] == 10001
    assert c["securityContext"]["readOnlyRootFilesystem"] and c["securityContext"]["capabilities"]["drop"] == ["ALL"]


def test_resources_follow_the_per_controller_targets() -> None:
    """requests: the process's own 64 Mi and 50 m of a core, and 10 Mi and 10 m per controller (the
    fleet's targets at rest); limits: twice the memory, 200 m + 100 m per controller
    (statefulset.yaml's comment)."""
    n = len(fleet()["controller"])
    r = container()["resources"]
    assert r["requests"] == {"cpu": f"{50 + 10 * n}m", "memory": f"{64 + 10 * n}Mi"}
    assert r["limits"] == {"cpu": f"{100 * n + 200}m", "memory": f"{2 * (64 + 10 * n)}Mi"}


def test_each_controllers_ports_are_those_its_services_and_the_pod_name(tmp_path: Path) -> None:
    container_ports = {p["name"]: p["containerPort"] for p in container()["ports"]}
    served: list[int] = []
    for name, ports in fleet_ports(tmp_path).items():
        served += ports.values()
        service = resource("Service", f"robot-cell-{name}")
        assert service["spec"]["clusterIP"] == "None"  # one robot, never load-balanced
        by_role = {p["name"]: p for p in service["spec"]["ports"]}
        assert {role: p["port"] for role, p in by_role.items()} == ports, name
        for role, port in ports.items():
            assert by_role[role]["targetPort"] == f"{name}-{role}"
            assert container_ports[f"{name}-{role}"] == port
    assert container_ports["web"] == WEB_PORT
    assert sorted(container_ports.values()) == sorted([*served, WEB_PORT])  # each once
    # the headless Service of the pods' DNS names, and the web view on it
    governing = resource("Service", "robot-cell")
    assert governing["spec"]["clusterIP"] == "None"
    assert [(p["name"], p["port"]) for p in governing["spec"]["ports"]] == [("web", WEB_PORT)]


def test_the_network_policy_guards_every_port_and_lets_the_cells_call_no_one() -> None:
    policy = resource("NetworkPolicy")["spec"]
    labels = resource("StatefulSet")["spec"]["template"]["metadata"]["labels"]
    assert policy["podSelector"]["matchLabels"].items() <= labels.items()
    assert policy["policyTypes"] == ["Ingress", "Egress"] and policy["egress"] == []
    (rule,) = policy["ingress"]
    assert all("podSelector" in source and "namespaceSelector" not in source for source in rule["from"])
    guarded = {p["port"] for p in rule["ports"]}
    assert guarded == {p["containerPort"] for p in container()["ports"]}


# -- the image and the compose cell ------------------------------------------------------------------


def test_build_image_tags_the_image_compose_and_the_statefulset_name() -> None:
    tag = subprocess.run(
        ["bash", str(DEPLOY / "build-image.sh"), "--print-tag"], capture_output=True, text=True, check=True, timeout=60
    ).stdout.strip()
    assert tag == f"simple-message-stack:{version()}"
    compose = yaml.safe_load((DEPLOY / "compose.yaml").read_text())
    for name, service in compose["services"].items():
        image = re.sub(r"\$\{VERSION:-([^}]*)\}", r"\1", service["image"])  # VERSION unset
        assert image == tag, name
        assert "${VERSION" in service["image"]
    assert container()["image"] == tag


def test_the_compose_cell_publishes_each_controllers_ports_on_loopback() -> None:
    compose = yaml.safe_load((DEPLOY / "compose.yaml").read_text())
    web_host_ports = []
    for name, service in compose["services"].items():
        args = service["command"]
        profile = args[args.index("--profile") + 1]
        assert args[args.index("--host") + 1] == "0.0.0.0", name  # else unreachable through the ports
        assert args[args.index("--web") + 1] == f"0.0.0.0:{WEB_PORT}", name
        published = {}
        for mapping in service["ports"]:
            address, host, inside = mapping.rsplit(":", 2)
            assert address == "${CELL_ADDRESS:-127.0.0.1}", name  # this machine only, by default
            published[int(inside)] = int(host)
        expected = set(served_ports(EmulatorConfig(profile=profile)).values())
        assert set(published) == expected | {WEB_PORT}, name
        assert all(published[p] == p for p in expected), name  # the vendor's own port numbers
        web_host_ports.append(published[WEB_PORT])
    assert len(set(web_host_ports)) == len(web_host_ports)


def test_the_containerfile_declares_every_profiles_ports_and_runs_robot_server_unprivileged() -> None:
    text = (DEPLOY / "Containerfile").read_text()
    (expose,) = re.findall(r"^EXPOSE (.*)$", text, re.M)
    ports = {int(p) for p in expose.split()}
    for name in ("generic", "abb", "fanuc", "staubli", "motoros"):
        d = dialect(name)
        assert {d.motion_port, d.state_port} <= ports, name
    assert dialect("motoros").io_port in ports and WEB_PORT in ports
    assert 'ENTRYPOINT ["robot-server"]' in text
    assert 'CMD ["--host", "0.0.0.0"]' in text
    assert re.search(r"^USER 10001:10001$", text, re.M)
    assert re.search(r'^HEALTHCHECK .* CMD \["robot-server-healthcheck"\]$', text, re.M)
    assert re.search(r"^FROM \$\{BASE\} AS python$", text, re.M) and "ARG BASE=debian:bookworm-slim" in text
    assert '"simple-message-stack[web]==${VERSION}"' in text and "--no-index" in text


def test_the_shell_scripts_are_shellcheck_clean() -> None:
    shellcheck = shutil.which("shellcheck")
    if shellcheck is None:
        pytest.skip("shellcheck is not installed (apt-get install shellcheck)")
    scripts = sorted(DEPLOY.glob("*.sh"))
    assert scripts
    result = subprocess.run([shellcheck, *map(str, scripts)], check=False, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr


# -- the health check --------------------------------------------------------------------------------


def test_the_health_check_reads_robot_servers_options_and_fleet_files(tmp_path: Path) -> None:
    hc = healthcheck()
    (one,) = hc.controllers(hc.server_options(["--profile", "fanuc", "--motion-port", "12000", "--model", "ur5"]))
    assert (one.dialect.name, one.host, one.ports) == ("fanuc", "127.0.0.1", {"motion": 12000, "state": 11002})
    assert one.wire.byte_order == "big"  # the family's
    (one,) = hc.controllers(hc.server_options(["--host", "0.0.0.0", "--byte-order", "big", "--float64"]))
    assert (one.dialect.name, one.host, one.wire.byte_order, one.wire.real_size) == ("generic", "0.0.0.0", "big", 8)
    path = tmp_path / FLEET_KEY
    path.write_text(resource("ConfigMap")["data"][FLEET_KEY])
    found = hc.controllers(hc.server_options(["--fleet", str(path)]))
    assert [(c.name, c.dialect.name) for c in found] == [(t["name"], t["profile"]) for t in fleet()["controller"]]
    assert {c.name: c.ports for c in found} == fleet_ports(tmp_path)
    assert {c.host for c in found} == {"0.0.0.0"}
    path.write_text("[[controller]]\nname = 'x'\nprofile = 'nosuch'\n")
    assert hc.main(["--fleet", str(path)]) == 2
    path.write_text("not toml [")
    assert hc.main(["--fleet", str(path)]) == 2


def test_the_health_check_finds_the_server_and_its_listening_ports(tmp_path: Path) -> None:
    hc = healthcheck()
    for pid, argv in (
        ("1", [b"/sbin/docker-init", b"--"]),
        ("7", [b"/opt/robot-server/bin/python3", b"/opt/robot-server/bin/robot-server", b"--profile", b"abb"]),
        ("9", [b"python3", b"-m", b"robot_server", b"--fleet", b"x.toml"]),
    ):
        (tmp_path / pid).mkdir()
        (tmp_path / pid / "cmdline").write_bytes(b"\0".join(argv) + b"\0")
    (tmp_path / "self").mkdir()
    assert hc.find_server(tmp_path) == ["--profile", "abb"]  # the lowest PID
    net = tmp_path / "net"
    net.mkdir()
    header = "  sl  local_address rem_address   st tx_queue rx_queue tr tm->when retrnsmt   uid  timeout inode\n"
    (net / "tcp").write_text(
        header
        + "   0: 00000000:2AF8 00000000:0000 0A 00000000:00000000 00:00000000 00000000 10001 0 1\n"  # 11000 LISTEN
        + "   1: 0100007F:2AFA 0100007F:9C40 01 00000000:00000000 00:00000000 00000000 10001 0 2\n"  # 11002 ESTABLISHED
    )
    assert hc.listening(11000, net) and not hc.listening(11002, net) and not hc.listening(50240, net)
    assert hc.main(["--profile", "fanuc", "--motion-port", "1", "--state-port", "2"]) == 1  # nothing listens


@pytest.mark.parametrize("profile", ["generic", "motoros", "abb"])
async def test_the_health_check_pings_where_the_family_answers_and_sends_nothing_elsewhere(profile: str) -> None:
    hc = healthcheck()
    emu = Emulator(EmulatorConfig(profile=profile, motion_port=0, state_port=0, io_port=0))
    await emu.start()
    try:
        d = dialect(profile)
        ports = {"motion": emu.ports["motion"], "state": emu.ports["state"]}
        c = hc.Controller(profile, d, "0.0.0.0", ports, LE32)
        ok, line = await hc.check(c, 5.0)
        assert ok, line
        if d.ping:
            assert line.startswith(f"PING on 127.0.0.1:{ports['motion']} answered")
        else:
            assert "nothing sent" in line
            assert not emu.motion_server.sessions  # not even a connection
    finally:
        await emu.close()
    ok, line = await hc.check(c, 5.0)
    assert not ok and line.startswith("not listening: motion")


# -- the image, built and run ------------------------------------------------------------------------


@pytest.mark.slow
def test_the_image_builds_runs_and_passes_conformance() -> None:
    """deploy/test-image.sh: build, run with podman on loopback, PING, conformance, health, SIGTERM,
    the Kubernetes cell's command and the compose cell. .ci/run runs the script itself, in its
    podman section, and sets DEPLOY_IMAGE_TESTED=1 so that it is not run twice."""
    if os.environ.get("DEPLOY_IMAGE_TESTED") == "1":
        pytest.skip("deploy/test-image.sh ran in .ci/run's podman section (its output is there)")
    if shutil.which("podman") is None:
        pytest.skip("podman is not installed (apt-get install podman mmdebstrap uidmap)")
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    result = subprocess.run(
        ["bash", str(DEPLOY / "test-image.sh")], check=False, capture_output=True, text=True, timeout=1800, env=env
    )
    if result.returncode == 77:
        pytest.skip(result.stderr.strip().splitlines()[-1])
    assert result.returncode == 0, result.stdout[-6000:] + result.stderr[-3000:]
    assert re.search(r"^image: \d+ passed, 0 failed$", result.stdout, re.M)
