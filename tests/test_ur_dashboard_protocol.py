"""The simulated controller's dashboard server (TCP 29999), protocol-test style: each case is
a list of (command sent, reply expected) pairs spoken over a raw socket, as a UR e-Series 5.11
words them; then the same server through ur-rtde's real ``DashboardClient``."""

from __future__ import annotations

import socket
import time

import dashboard_client  # ur-rtde is a hard dependency: missing it must fail, not skip
import pytest

from robot.sim_controller import SimRig, SimulatedController
from robot.ur_wire import POLYSCOPE_VERSION

UNLOCK_DELAY_S = 1.0


@pytest.fixture(scope="module")
def sim():
    with SimulatedController(SimRig(unlock_delay_s=UNLOCK_DELAY_S), seed=7) as s:
        yield s


class Dashboard:
    """A line-oriented raw client: one request line out, one reply line in."""

    def __init__(self, host: str) -> None:
        self.sock = socket.create_connection((host, 29999), timeout=2.0)
        self.file = self.sock.makefile("rb")
        self.welcome = self.file.readline().decode().strip()

    def ask(self, line: str) -> str:
        self.sock.sendall(line.encode() + b"\n")
        return self.file.readline().decode().rstrip("\n")

    def close(self) -> None:
        self.file.close()
        self.sock.close()


def check_pairs(host: str, pairs: list[tuple[str, str]]) -> None:
    d = Dashboard(host)
    try:
        assert d.welcome == "Connected: Universal Robots Dashboard Server"
        for request, expected in pairs:
            assert d.ask(request) == expected, request
    finally:
        d.close()


def test_status_queries(sim):
    check_pairs(
        sim.host,
        [
            ("PolyscopeVersion", POLYSCOPE_VERSION),
            ("robotmode", "Robotmode: RUNNING"),
            ("safetymode", "Safetymode: NORMAL"),
            ("safetystatus", "Safetystatus: NORMAL"),
            ("running", "Program running: false"),
            ("programState", "STOPPED <unnamed>"),
            ("is in remote control", "true"),
            ("get robot model", "UR5"),
        ],
    )


def test_unknown_command_is_named_in_the_reply(sim):
    check_pairs(sim.host, [("make coffee", "could not understand: 'make coffee'")])


def test_protective_stop_unlock_respects_the_delay(sim):
    sim.inject_protective_stop()
    refused = (
        "Cannot unlock protective stop until 5s after occurrence. "
        "Always inspect cause of protective stop before unlocking"
    )
    check_pairs(
        sim.host,
        [
            ("safetystatus", "Safetystatus: PROTECTIVE_STOP"),
            ("safetymode", "Safetymode: PROTECTIVE_STOP"),
            ("unlock protective stop", refused),
            ("safetystatus", "Safetystatus: PROTECTIVE_STOP"),
        ],
    )
    time.sleep(UNLOCK_DELAY_S + 0.05)
    check_pairs(
        sim.host,
        [
            ("unlock protective stop", "Protective stop releasing"),
            ("close safety popup", "closing safety popup"),
            ("safetystatus", "Safetystatus: NORMAL"),
        ],
    )
    assert not sim.protective_stopped


def test_stop_without_a_running_program_fails_like_a_ur(sim):
    check_pairs(sim.host, [("stop", "Failed to execute: stop"), ("quit", "Disconnected")])


def test_real_dashboard_client_reads_the_same_server(sim):
    d = dashboard_client.DashboardClient(sim.host)
    d.connect()
    try:
        assert d.isConnected()
        assert d.polyscopeVersion() == "5.11.1.108318"  # the client parses the version out
        assert d.isInRemoteControl() is True
        assert "NORMAL" in d.safetystatus()
        assert "RUNNING" in d.robotmode()
        assert d.running() is False
    finally:
        d.disconnect()
    assert ("is in remote control", "true") in sim.dashboard_log()
