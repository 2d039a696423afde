"""Test set-up shared by every test module."""
import touch4d  # noqa: F401  first: it caps BLAS thread pools (tiny matrices, busy 2-core machines)

import random  # noqa: E402
from pathlib import Path  # noqa: E402

import pytest  # noqa: E402


@pytest.fixture
def can_group():
    """A CAN channel two processes share: python-can's udp_multicast on a group of this test's own.

    Every group shares one UDP port, and Linux hands a socket the datagrams of every group joined
    on the machine: tests of concurrent runs (several checkouts on one machine) would hear each
    other's boards. So a lock file lets one such test run at a time. Skipped where this machine
    cannot send multicast (a container without a multicast route)."""
    import fcntl
    import tempfile

    import can

    group = f"239.{random.randrange(1, 255)}.{random.randrange(1, 255)}.{random.randrange(1, 255)}"
    with open(Path(tempfile.gettempdir()) / "touch4d-udp-multicast-tests.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            with can.Bus(interface="udp_multicast", channel=group) as a, \
                    can.Bus(interface="udp_multicast", channel=group) as b:
                a.send(can.Message(arbitration_id=0x7FF, data=b"probe", is_extended_id=False))
                if b.recv(2.0) is None:
                    raise OSError("nothing came back")
        except (OSError, can.CanError) as exc:
            pytest.skip(f"no multicast CAN between processes here (python-can udp_multicast: {exc})")
        yield group
