"""The controller's python-can link (error classes, reopen) and the standalone emulator command."""
from __future__ import annotations

import errno
import threading
import time
import uuid
from pathlib import Path

import can
import pytest

from touch4d.cli import main as cli_main
from touch4d.boards.config import load_glove_can
from touch4d.boards.link import BUS_OFF_REOPEN_AFTER, CanLink, classify
from touch4d.boards.protocol import GloveProtocol

TEST_GLOVE = Path(__file__).parent / "data" / "glove_can_test.yaml"
PROTO = GloveProtocol(load_glove_can(TEST_GLOVE))


@pytest.mark.parametrize("exc, kind", [
    (can.CanOperationError("Failed to transmit: No buffer space available", errno.ENOBUFS), "tx_queue_full"),
    (can.CanOperationError("Transmit buffer full"), "tx_queue_full"),
    (can.CanOperationError("Could not send message to one or more recipients"), "tx_queue_full"),
    (can.CanOperationError("Failed to transmit: Network is down", errno.ENETDOWN), "bus_off"),
    (can.CanOperationError("Cannot operate on a closed bus"), "bus_closed"),
    (can.CanOperationError("Failed to transmit: Input/output error", errno.EIO), "send_error"),
])
def test_classify(exc, kind):
    assert classify(exc) == kind


class Clock:
    t = 0.0

    def __call__(self):
        return self.t


def test_a_closed_bus_is_reopened_at_most_every_reopen_period():
    channel = f"link-{uuid.uuid4().hex}"
    clock = Clock()
    with can.Bus(interface="virtual", channel=channel) as peer:
        link = CanLink("virtual", channel, 500000, clock=clock)
        assert link.send(PROTO.nmt("START")) is None
        assert peer.recv(timeout=1.0).arbitration_id == 0
        link.bus.shutdown()  # closed under the link's feet
        assert link.send(PROTO.nmt("STOP")) == "bus_closed" and link.bus is None
        assert link.send(PROTO.nmt("STOP")) == "bus_closed"  # within the reopen period: not retried yet
        clock.t += 1.0
        assert link.send(PROTO.nmt("STOP")) is None
        assert peer.recv(timeout=1.0).data[0] == 2
        link.close()


def test_an_interface_that_cannot_open_is_reported_not_raised():
    link = CanLink("no-such-interface", "x", 500000, clock=Clock())
    assert link.send(PROTO.nmt("START")) == "open_failed"
    assert "no-such-interface" in link.last_error
    assert link.receive() == ([], None)


def test_repeated_bus_off_closes_the_bus_for_a_reopen():
    class Down:
        def send(self, msg, timeout=None):
            raise can.CanOperationError("Failed to transmit: Network is down", errno.ENETDOWN)

        def shutdown(self):
            self.closed = True

    down = Down()
    link = CanLink("virtual", f"link-{uuid.uuid4().hex}", 500000, bus=down, clock=Clock())
    for _ in range(BUS_OFF_REOPEN_AFTER - 1):
        assert link.send(PROTO.nmt("START")) == "bus_off"
    assert link.bus is down
    assert link.send(PROTO.nmt("START")) == "bus_off"
    assert link.bus is None and down.closed


@pytest.mark.timeout(60)
def test_touch4d_glove_emulate_runs_standalone_on_a_channel(capsys):
    channel = f"standalone-{uuid.uuid4().hex}"
    with can.Bus(interface="virtual", channel=channel) as bus:
        result = {}
        thread = threading.Thread(target=lambda: result.setdefault("rc", cli_main([
            "glove", "emulate", "--glove", str(TEST_GLOVE), "--interface", "virtual", "--channel", channel,
            "--duration", "1.0", "--print-period", "0.25"])))
        thread.start()
        try:
            statuses = {}
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline and thread.is_alive():  # keep its watchdog fed till it ends
                bus.send(PROTO.nmt("START"))
                bus.send(PROTO.duty(4, [10] * 8, 1))
                m = bus.recv(timeout=0.05)
                while m is not None:
                    f = PROTO.decode(m)
                    if f is not None and f.kind == "status":
                        statuses[f.board] = PROTO.state_name(f)
                    m = bus.recv(timeout=0)
            assert statuses.get(4) == "ACTIVE"
        finally:
            thread.join(timeout=30)
    assert result["rc"] == 0
    out = capsys.readouterr().out
    assert "board 4: operational active levels [10, 10, 10, 10, 10, 10, 10, 10]" in out


def test_touch4d_glove_emulate_reports_a_bus_that_does_not_open(capsys):
    rc = cli_main(["glove", "emulate", "--glove", str(TEST_GLOVE), "--interface", "no-such-interface",
                   "--channel", "x", "--duration", "0.1"])
    assert rc == 2 and "no-such-interface" in capsys.readouterr().err


@pytest.mark.parametrize("period", ["0", "-1", "nan", "inf"])
def test_touch4d_glove_emulate_refuses_a_print_period_that_is_not_positive(capsys, period):
    rc = cli_main(["glove", "emulate", "--glove", str(TEST_GLOVE), "--duration", "0.1", "--print-period", period])
    assert rc == 2 and "--print-period" in capsys.readouterr().err
