"""The asyncio event loop touch4d's own loops run on: uvloop's (libuv, in C) where it is installed,
else asyncio's. The page server and the study server turn a loop for every page message and frame:
uvloop's turn costs a fraction of asyncio's Python one (bench/bench_serve.py measures both).
"""
from __future__ import annotations

import asyncio

try:
    import uvloop
except ImportError:  # pragma: no cover - a platform without it (Windows) runs asyncio's own
    uvloop = None


def new_event_loop(serves_tls: bool = False) -> asyncio.AbstractEventLoop:
    """A new event loop of the kind above (not set as the thread's current loop). `serves_tls`: a
    loop whose server starts TLS itself (touch4d.web.server's guard, `start_tls`) is asyncio's:
    on uvloop's, a browser's secure WebSocket to that server never opened (tests/test_web_browser.py)."""
    return uvloop.new_event_loop() if kind(serves_tls) == "uvloop" else asyncio.new_event_loop()


def kind(serves_tls: bool = False) -> str:
    """Which loop `new_event_loop` makes: "uvloop" or "asyncio" (for a benchmark's header)."""
    return "uvloop" if uvloop is not None and not serves_tls else "asyncio"
