"""Nothing listens beyond loopback unless the user asks: ``run --live`` and every emulator refuse a
non-loopback address with one line (exit 2) unless ``--allow-network`` is given."""

from __future__ import annotations

import socket

import pytest
from helpers import one_line_error

from hapticlab.core.errors import ConfigError
from hapticlab.core.host.options import OptionError, listen_address
from hapticlab.sessions.cli import main
from hapticlab.sessions.config import apply_overrides, load_config
from hapticlab.sessions.live import build_session, run_session


@pytest.mark.parametrize("host", ["127.0.0.1", "127.0.0.96", "::1", "[::1]", "localhost"])
def test_a_loopback_address_is_taken_as_it_is(host):
    assert listen_address("--live", host) == host


@pytest.mark.parametrize("host", ["0.0.0.0", "::", "192.168.1.20", "10.0.0.3", "lab-pc.example.org", ""])
def test_any_other_address_needs_the_network_asked_for(host):
    with pytest.raises(OptionError, match=r"^--address: must be a loopback address .* to anyone on the network$"):
        listen_address("--address", host, exposes="the emulated device")
    assert listen_address("--address", host, allow_network=True) == host


def test_run_live_on_every_interface_is_refused_before_the_session_is_built(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    line = one_line_error(capsys, ["run", "--live", "0.0.0.0:8765", "--set", "session.realtime=false"])
    assert "--live: must be a loopback address" in line and "/haptic/command included" in line, line
    assert "--allow-network" in line
    assert list(tmp_path.iterdir()) == []  # no recording started


def test_the_python_api_refuses_it_too(tmp_path):
    config, _ = load_config("demo")
    session = build_session(apply_overrides(config, ["session.realtime=false", "session.duration=0.1"]))
    with pytest.raises(ConfigError, match=r"^--live: must be a loopback address"):
        run_session(session, out=tmp_path / "x.mcap", live="192.168.1.20:8765")
    assert not (tmp_path / "x.mcap").exists()


@pytest.mark.parametrize(
    ("argv", "option"),
    [
        (["emulate", "netft", "--address", "0.0.0.0"], "--address"),
        (["emulate", "ur", "--address", "10.1.2.3"], "--address"),
        (["emulate", "lab", "--netft", "0.0.0.0"], "--netft"),
        (["emulate", "lab", "--ur", "192.168.0.7"], "--ur"),
    ],
)
def test_an_emulator_on_a_network_address_is_refused(capsys, argv, option):
    line = one_line_error(capsys, [*argv, "--duration", "0.1"])
    assert f"{option}: must be a loopback address" in line and "the emulated device" in line, line


def free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_with_allow_network_the_emulator_serves_every_interface(capsys):
    rdt, http = free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_STREAM)
    argv = ["emulate", "netft", "--address", "0.0.0.0", "--allow-network", "--duration", "0.2"]
    code = main([*argv, "--rdt-port", str(rdt), "--http-port", str(http)])
    out = capsys.readouterr().out
    assert code == 0 and "0.0.0.0" in out.splitlines()[0], out
