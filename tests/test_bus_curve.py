"""Two-machine security: with CURVE on, only allow-listed keys are heard (tested on loopback)."""
import time

import numpy as np
import pytest
import zmq

from touch4d.bus import CurveKeys, Node
from touch4d.bus.config import BusConfig
from touch4d.bus.keys import keygen
from touch4d.bus.testing import collect, running_broker, wait_until
from touch4d.messages import MotorCommand, encode

pytestmark = pytest.mark.timeout(60)


def keys(folder, name):
    import zmq.auth

    public, secret = zmq.auth.load_certificate(keygen(folder, name)[1])
    return public.decode(), secret.decode()


def command(value):
    return MotorCommand(names=["m0"], intensity=np.array([value]))


def stranger(ctx, endpoint, kind, server_public=None, pair=None):
    sock = ctx.socket(kind)
    sock.linger = 0
    if pair is not None:
        sock.curve_serverkey = server_public.encode()
        sock.curve_publickey, sock.curve_secretkey = pair[0].encode(), pair[1].encode()
    sock.connect(endpoint)
    return sock


def test_only_allow_listed_peers_are_heard(tmp_path):
    server = keys(tmp_path, "broker")
    pc = keys(tmp_path, "pc")
    intruder = keys(tmp_path, "intruder")
    curve = CurveKeys(server_public=server[0], server_secret=server[1], client_public=pc[0], client_secret=pc[1],
                      authorized=(pc[0],))
    ctx = zmq.Context()
    try:
        with running_broker(curve=curve) as bus:
            assert bus.curve is not None
            with Node("motors", bus=bus) as motors, Node("tactile", bus=bus) as tactile:
                heard = collect(motors, "tactile/motors", MotorCommand)
                pub = tactile.create_publisher("tactile/motors", MotorCommand)
                pub.publish(command(0.25))
                wait_until(lambda: heard, timeout=10, spin=motors)  # keyed peers talk

                plain = stranger(ctx, bus.pub_endpoint, zmq.PUB)
                wrong_key = stranger(ctx, bus.pub_endpoint, zmq.PUB, server[0], intruder)
                eavesdropper = stranger(ctx, bus.sub_endpoint, zmq.SUB, server[0], intruder)
                eavesdropper.subscribe(b"")
                bad = command(1.0)
                bad.stamp = bad.source_stamp = time.time()
                for _ in range(100):
                    for sock in (plain, wrong_key):
                        sock.send_multipart([b"tactile/motors", encode(bad)])
                    pub.publish(command(0.5))
                    motors.spin_once(0.01)
                pub.publish(command(0.75))
                wait_until(lambda: heard[-1].intensity[0] == 0.75, timeout=10, spin=motors)
                motors.spin(0.3)
                assert eavesdropper.poll(200) == 0, "an unknown key must not receive anything"
        values = {float(m.intensity[0]) for m in heard}
        assert values == {0.25, 0.5, 0.75}
        assert len(heard) == 102
    finally:
        ctx.destroy(linger=0)


def test_a_node_without_the_servers_key_cannot_join(tmp_path, caplog):
    server = keys(tmp_path, "broker")
    pc = keys(tmp_path, "pc")
    curve = CurveKeys(server_public=server[0], server_secret=server[1], authorized=(pc[0],))
    with running_broker(curve=curve) as bus:
        intruder = keys(tmp_path, "intruder")
        their_bus = BusConfig(connect_host=bus.connect_host, pub_port=bus.pub_port, sub_port=bus.sub_port,
                              curve=CurveKeys(server_public=server[0], client_public=intruder[0],
                                              client_secret=intruder[1]))
        with caplog.at_level("WARNING"):
            with Node("intruder", bus=their_bus, connect_timeout=0.5, heartbeat=False):
                pass
    assert "broker not reached" in caplog.text
