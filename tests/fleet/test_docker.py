"""The docker files cannot be run here (no Docker engine): check that the compose file is valid
YAML of the right shape, that every command it runs is one ``uav-console`` accepts, and that
everything the Dockerfile copies exists."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest
import yaml

from server.cli import _parser
from server.settings import ROOT

DOCKER = ROOT / "docker"


def compose() -> dict:
    with (DOCKER / "compose.yaml").open() as f:
        return yaml.safe_load(f)


def test_compose_shape() -> None:
    c = compose()
    services = c["services"]
    assert {"zenohd", "keys", "central", "sim1", "sim2", "vehicle1", "vehicle2"} <= set(services)
    nets = c["networks"]["fleet"]["ipam"]["config"][0]["subnet"]
    assert nets == "172.28.0.0/24"
    for name, svc in services.items():
        assert list(svc["networks"]) == ["fleet"], name
        if name != "zenohd":  # Eclipse's own router image, unchanged
            assert svc["build"]["dockerfile"] == "docker/Dockerfile"
    # the bus: the central's router joins zenohd; the vehicles join the central's router
    central = services["central"]["command"]
    assert central[central.index("--bus-connect") + 1] == "tcp/zenohd:7447"
    assert "--no-multicast-scouting" in services["zenohd"]["command"]
    # each vehicle flies its own simulator, addressed by that container's IP
    for k in (1, 2):
        sim_ip = services[f"sim{k}"]["networks"]["fleet"]["ipv4_address"]
        cmd = services[f"vehicle{k}"]["command"]
        assert cmd[cmd.index("--drone") + 1] == sim_ip
        # the whole vehicle, joining over the bus (a stray flag would not parse)
        assert _parser().parse_args(cmd).bus_connect == ["tls/central:7447"]
        assert services[f"sim{k}"]["command"][2] == sim_ip
        # its own key, made by the one-shot `keys` service in the central's data volume
        assert cmd[cmd.index("--key-file") + 1] == f"/central/vehicle-keys/uav{k}.key"
        assert f"uav{k}" in services["keys"]["command"]
        assert services[f"vehicle{k}"]["volumes"] == ["central-data:/central:ro"]
        # the central listens off loopback, so over TLS: its CA is in its data volume
        assert cmd[cmd.index("--bus-connect") + 1] == "tls/central:7447"
        assert cmd[cmd.index("--bus-ca") + 1] == "/central/tls/ca.pem"
    assert services["central"]["hostname"] == "central"  # named by its bus certificate


@pytest.mark.parametrize("service", ["keys", "central", "sim1", "sim2", "vehicle1", "vehicle2"])
def test_compose_commands_exist(service: str) -> None:
    cmd = [
        re.sub(r"\$\{UAVC_TOKEN[^}]*\}", "tok", a)
        for a in compose()["services"][service]["command"]
    ]
    args = _parser().parse_args(cmd)  # exits (SystemExit) on an unknown command or flag
    assert args.command == cmd[0]


def test_dockerfile_copies_existing_paths() -> None:
    text = (DOCKER / "Dockerfile").read_text()
    copied = [
        p for line in text.splitlines() if line.startswith("COPY") for p in shlex.split(line)[1:-1]
    ]
    assert copied
    for p in copied:
        assert (ROOT / p).exists(), p
    assert 'ENTRYPOINT ["uav-console"]' in text
    assert Path(ROOT / "pyproject.toml").read_text().count('uav-console = "server.cli:main"') == 1
