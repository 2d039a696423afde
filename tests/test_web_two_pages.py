"""Two pages at once, with the same token: the page that drives the hand keeps it while it tracks;
the other one's input is refused, counted in the heartbeat, logged with its address, and the page
is told; once the first page goes, the second drives. The webxr node runs as its own process,
the pages are WebSocket clients speaking the page's protocol."""
import asyncio
import json
import threading
import time

import aiohttp
import numpy as np
import pytest

from touch4d.bus import Node
from touch4d.bus.testing import collect, free_port, node_process, running_broker, wait_until
from touch4d.messages import Heartbeat, HandPose
from touch4d.web.protocol import unpack_frame

pytestmark = pytest.mark.timeout(90)
GRIP = {"a": [0.05, 1.2, -0.45, 0.0, 0.0, 0.0, 1.0], "b": [-0.05, 1.2, -0.45, 0.0, 0.0, 0.0, 1.0]}
X = {"a": 0.2, "b": -0.2}   # the hand's x on the screen for each grip (config/calibration.yaml: 0.5 m box)


def tracked(grip) -> str:
    return json.dumps({"type": "input", "time": time.time() * 1000, "tracking": True, "head": None, "sources": [
        {"handedness": "right", "grip": grip, "trigger": 0, "buttons": [], "joints": None}]})


def test_a_second_page_cannot_take_the_hand_from_the_one_that_drives_it():
    port = free_port()
    with running_broker() as bus, node_process("webxr", bus, params={"port": port, "tracker": True,
                                                                     "save_calibration": False,
                                                                     "stale_s": 0.09}) as proc:
        # stale_s at the most the node allows: a loaded machine may pause the pages' script for a while
        proc.wait_for_line("WebXR page", timeout=30)
        probe = Node("probe", bus=bus, heartbeat=False)
        beats = collect(probe, "node/heartbeat", Heartbeat)
        poses = collect(probe, "hand/pose", HandPose)
        told = {}
        try:
            async def pages():
                url = f"http://127.0.0.1:{port}/ws"
                async with aiohttp.ClientSession() as session:
                    a = await session.ws_connect(url)
                    b = await session.ws_connect(url)
                    for ws in (a, b):
                        assert unpack_frame(await ws.receive_bytes())[0]["kind"] == "setup"
                    for _ in range(5):                          # a tracks first, never silent for long
                        await a.send_str(tracked(GRIP["a"]))
                        await asyncio.sleep(0.01)
                    await b.send_str('{"type": "session", "mode": "immersive", "active": true}')

                    async def frames(ws, name):
                        async for msg in ws:
                            if msg.type == aiohttp.WSMsgType.BINARY:
                                header = unpack_frame(msg.data)[0]
                                if header["kind"] == "driver":
                                    told.setdefault(name, []).append(header["driver"])
                    readers = [asyncio.ensure_future(frames(a, "a")), asyncio.ensure_future(frames(b, "b"))]
                    for _ in range(50):                        # 0.5 s of both pages tracking
                        await a.send_str(tracked(GRIP["a"]))
                        await b.send_str(tracked(GRIP["b"]))
                        await asyncio.sleep(0.01)
                    probe_mark.append(time.time())            # before a goes: b's backlog may drive at once
                    await a.close()                            # the driving page goes
                    for _ in range(30):
                        await b.send_str(tracked(GRIP["b"]))
                        await asyncio.sleep(0.01)
                    await asyncio.sleep(0.2)
                    await b.close()
                    for r in readers:
                        r.cancel()

            probe_mark, loop_done = [], []
            thread = threading.Thread(target=lambda: loop_done.append(asyncio.run(pages())), daemon=True)
            thread.start()
            wait_until(lambda: (probe.spin_once(0.01), not thread.is_alive())[-1], timeout=60)
            assert loop_done, "the pages' script failed"

            def refused():
                stats = [b.stats for b in beats if b.node == "webxr"]
                return stats and stats[-1].get("page_not_driver", 0) >= 25 and stats[-1]
            assert wait_until(lambda: (probe.spin_once(0.01), refused())[-1], timeout=10)
        finally:
            probe.shutdown()
        valid = [p for p in poses if p.valid]
        before = [p.position[0] for p in valid if p.stamp < probe_mark[0]]
        after = [p.position[0] for p in valid if p.stamp > probe_mark[0] + 0.1]
        assert len(before) >= 25 and np.allclose(before, X["a"], atol=1e-6)      # page a's hand only
        assert len(after) >= 5 and np.allclose(after, X["b"], atol=1e-6)        # then page b's
        assert told.get("b") == [False, True] and told.get("a") == [True]
        assert "page 2 (127.0.0.1:" in proc.text and "refused until that page stops tracking" in proc.text
