"""Consumers that never read cannot take the memory of the broker or of the WebXR node.

- The broker: a subscriber process that never reads while 200 MB go through. The broker keeps at
  most `hwm` messages for it (ZeroMQ's high-water mark, the bus file's `hwm`, always finite), drops
  the rest for that subscriber only, and the others get everything.
- The page server: 100 idle WebSocket connections at once. Only `max_pages` are accepted (the rest
  get HTTP 503, counted); those that never read answer no ping and are closed by the heartbeat
  (counted as `page_unresponsive`), which frees their places.
Peak memory is read from /proc (VmHWM) of each process."""
from __future__ import annotations

import asyncio
import os
import subprocess
import sys
import time

import aiohttp
import pytest
import zmq

from touch4d.bus import Node
from touch4d.bus.testing import ProcessOutput, collect, free_port, node_process, running_broker, wait_until
from touch4d.messages import Heartbeat

pytestmark = pytest.mark.timeout(90)
MB = 1 << 20


def memory(pid: int, key: str = "VmRSS") -> float:
    """A process's resident memory (VmRSS) or its peak (VmHWM), in MB."""
    with open(f"/proc/{pid}/status") as f:
        return next(int(line.split()[1]) / 1024 for line in f if line.startswith(key + ":"))


def stuck_broker(tmp_path, hwm: int, messages: int = 10000, size: int = 10000) -> dict:
    """Push messages x size bytes through a broker with a subscriber that never reads."""
    pub_port, sub_port = free_port(), free_port()
    bus_file = tmp_path / "bus.yaml"
    bus_file.write_text(f"broker: {{bind: 127.0.0.1, pub_port: {pub_port}, sub_port: {sub_port}}}\n"
                        f"connect: 127.0.0.1\nhwm: {hwm}\n")
    start = [sys.executable, "-u", "-c"]
    broker = ProcessOutput(subprocess.Popen([sys.executable, "-u", "-m", "touch4d.cli", "bus", "broker", "--bus",
                                             str(bus_file)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT))
    never_reads = ProcessOutput(subprocess.Popen(start + [
        "import time, zmq; s = zmq.Context().socket(zmq.SUB); s.setsockopt(zmq.SUBSCRIBE, b''); "
        f"s.connect('tcp://127.0.0.1:{sub_port}'); print('subscribed', flush=True); time.sleep(600)"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT))
    ctx = zmq.Context()
    try:
        broker.wait_for_line("broker: publishers connect", timeout=30)
        never_reads.wait_for_line("subscribed", timeout=30)
        reader = ctx.socket(zmq.SUB)
        reader.rcvhwm = 0
        reader.setsockopt(zmq.SUBSCRIBE, b"")
        reader.connect(f"tcp://127.0.0.1:{sub_port}")
        pub = ctx.socket(zmq.PUB)
        pub.sndhwm = 0
        pub.connect(f"tcp://127.0.0.1:{pub_port}")
        time.sleep(0.5)   # both subscriptions have reached the broker
        base = memory(broker.pid)
        payload, got = os.urandom(size), 0
        for i in range(messages):
            pub.send_multipart([b"big/x", payload])
            # The reader keeps up (never more than hwm / 2 behind, however loaded the machine);
            # the other one never reads.
            while reader.poll(0 if i - got < hwm // 2 else 100):
                reader.recv_multipart()
                got += 1
                if i - got < hwm // 4:
                    break
        # The rest still on its way: a loaded machine may hold the broker back for a second or more;
        # a message lost stays lost however long this waits.
        while got < messages and reader.poll(5000):
            reader.recv_multipart()
            got += 1
        return {"base": base, "peak": memory(broker.pid, "VmHWM"), "got": got, "sent": messages}
    finally:
        ctx.destroy(linger=0)
        for p in (broker, never_reads):
            p.proc.kill()
            p.proc.wait()
            p.join()


def test_a_subscriber_that_never_reads_costs_the_broker_at_most_its_high_water_mark(tmp_path):
    r = stuck_broker(tmp_path, hwm=1000)
    # 100 MB went through; the broker held at most hwm x 10 kB = 10 MB of it for the stuck subscriber.
    assert r["peak"] - r["base"] < 30, r
    assert r["got"] == r["sent"], r          # the reading subscriber lost nothing


def test_idle_pages_are_limited_and_closed_by_the_heartbeat():
    port, attempts, limit = free_port(), 100, 20
    with running_broker() as bus, node_process("webxr", bus, params={"port": port, "max_pages": limit,
                                                                     "save_calibration": False}) as proc:
        proc.wait_for_line("WebXR page", timeout=30)
        base = memory(proc.pid)
        probe = Node("probe", bus=bus, heartbeat=False)
        beats = collect(probe, "node/heartbeat", Heartbeat)
        result = {}

        async def flood():
            url = f"http://127.0.0.1:{port}/ws"
            async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(limit=0)) as session:
                tries = await asyncio.gather(*[session.ws_connect(url, autoping=False) for _ in range(attempts)],
                                             return_exceptions=True)
                idle = [t for t in tries if not isinstance(t, BaseException)]
                refused = [t for t in tries if isinstance(t, aiohttp.WSServerHandshakeError) and t.status == 503]
                result.update(idle=len(idle), refused=len(refused))
                await asyncio.sleep(4.0)   # they never read: no pong, closed by the server's heartbeat
                async with session.ws_connect(url) as ws:   # their places are free again
                    result["later"] = (await ws.receive()).type == aiohttp.WSMsgType.BINARY
                for ws in idle:
                    await ws.close()

        try:
            asyncio.run(flood())
            stats = wait_until(lambda: (probe.spin_once(0.01), [b.stats for b in beats if b.node == "webxr"
                                        and b.stats.get("page_unresponsive", 0) >= limit])[-1], timeout=10)
        finally:
            probe.shutdown()
        peak = memory(proc.pid, "VmHWM")
    assert result == {"idle": limit, "refused": attempts - limit, "later": True}
    assert stats[-1]["page_over_limit"] == attempts - limit and stats[-1]["page_unresponsive"] == limit
    assert peak - base < 40, (base, peak)
