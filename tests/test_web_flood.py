"""One page floods the webxr node (its own process, on loopback, a bounded number of messages): its
inputs reach the bus at most at a headset's rate with the latest pose kept, its re-centring at most
once a second with the calibration file written seldom and whole, and the node's heartbeat goes on."""
import asyncio
import json
import shutil
import time
from pathlib import Path

import aiohttp
import pytest

from touch4d.bus import Node
from touch4d.bus.testing import collect, free_port, node_process, running_broker, wait_until
from touch4d.messages import HandPose, Heartbeat
from touch4d.web.inbox import MAX_INPUT_HZ
from touch4d.web.protocol import unpack_frame

pytestmark = pytest.mark.timeout(120)
REPO = Path(__file__).resolve().parents[1]


def tracked(x: float) -> str:
    return json.dumps({"type": "input", "time": time.time() * 1000, "tracking": True, "head": None, "sources": [
        {"handedness": "right", "grip": [x, 1.2, -0.45, 0.0, 0.0, 0.0, 1.0], "trigger": 0, "buttons": [],
         "joints": None}]})


def test_a_flooding_page_is_paced_and_its_recentring_limited(tmp_path):
    calibration = tmp_path / "calibration.yaml"
    shutil.copy(REPO / "config/calibration.yaml", calibration)
    port = free_port()
    with running_broker() as bus, node_process("webxr", bus, params={
            "port": port, "tracker": True, "calibration": str(calibration)}) as proc:
        proc.wait_for_line("WebXR page", timeout=30)
        probe = Node("probe", bus=bus, heartbeat=False)
        beats = collect(probe, "node/heartbeat", Heartbeat)
        poses = collect(probe, "hand/pose", HandPose)
        try:
            sent = {}

            async def flood():
                async with aiohttp.ClientSession() as session, \
                        session.ws_connect(f"http://127.0.0.1:{port}/ws") as ws:
                    assert unpack_frame(await ws.receive_bytes())[0]["kind"] == "setup"
                    t0 = time.monotonic()
                    for k in range(3000):                          # as fast as the socket takes them
                        await ws.send_str(tracked(0.0001 * (k % 100)))
                        if k % 10 == 0:                            # (the same place: the hand's x unchanged)
                            await ws.send_str(json.dumps({"type": "recenter", "head": [0, 1.7, 0, 0, 0, 0, 1]}))
                    await ws.send_str(tracked(0.05))               # the last word: 5 cm further right
                    sent["seconds"] = time.monotonic() - t0
                    await asyncio.sleep(0.5)

            asyncio.run(flood())

            def settled():
                stats = [b.stats for b in beats if b.node == "webxr"]
                # the page has closed: its counts are final
                return stats and stats[-1].get("page_connections") == 1 and stats[-1].get("pages") == 0 and stats[-1]
            stats = wait_until(settled, timeout=15, spin=probe)
        finally:
            probe.shutdown()
        valid = [p for p in poses if p.valid]
        seconds = sent["seconds"] + 0.5
        # paced: at most a headset's rate over the flood (and some slack for the clock's edges)
        assert len(valid) <= MAX_INPUT_HZ * seconds * 1.1 + 5, (len(valid), seconds)
        assert stats["page_inputs_replaced"] == 3001 - len(valid)     # each input published or replaced
        # the latest input is never lost: the last pose is the last input's, 5 cm right of all the others
        assert valid[-1].position[0] > max(p.position[0] for p in valid[:-1]) + 0.1
        # re-centring: at most once a second; the file written at most once per save_min_s, whole
        # (300 asked: those over the page's message rate dropped at the server, the rest refused by the bridge)
        assert 1 <= stats["recentred"] <= seconds + 1
        assert stats["recentred"] + stats["recenter_limited"] + stats["page_flooded"] == 300
        text = calibration.read_text()
        assert "center_m:" in text and len(text) < 2 * len((REPO / "config/calibration.yaml").read_text())
        assert [b for b in beats if b.node == "webxr"]              # the node's heartbeat went on


def test_a_placement_waiting_for_its_time_is_stored_when_the_node_stops(tmp_path):
    """Re-centred twice within save_min_s, then the node is stopped: the file holds the second placement."""
    calibration = tmp_path / "calibration.yaml"
    shutil.copy(REPO / "config/calibration.yaml", calibration)
    port = free_port()
    with running_broker() as bus, node_process("webxr", bus, params={
            "port": port, "tracker": True, "calibration": str(calibration)}) as proc:
        proc.wait_for_line("WebXR page", timeout=30)

        async def page():
            async with aiohttp.ClientSession() as session, session.ws_connect(f"http://127.0.0.1:{port}/ws") as ws:
                assert unpack_frame(await ws.receive_bytes())[0]["kind"] == "setup"
                await ws.send_str(tracked(0.0))
                for x in (0.0, 0.5):                   # the second a little over a second later
                    await ws.send_str(json.dumps({"type": "recenter", "head": [x, 1.7, 0, 0, 0, 0, 1]}))
                    await asyncio.sleep(1.3)

        asyncio.run(page())
        proc.wait_for_line("stored in", timeout=10)     # the first, stored at once
    # the screen is put 0.5 m in front of the head: its centre's x is the head's
    centre = [line for line in calibration.read_text().splitlines() if "center_m:" in line]
    assert len(centre) == 1 and float(centre[0].split("[", 1)[1].split(",")[0]) == pytest.approx(0.5)
