"""The WebXR page in a real browser, for tests and benchmarks: Debian's chromium driven by the
playwright package (no browser download), WebGL2 through SwiftShader without a GPU, and a Quest 3
emulated by iwer (npm, installed by `./dev test`) in place of a headset.

    with chromium() as browser:
        page = headset_page(browser, url)        # iwer installed before the page's own scripts
        enter_vr(page)                           # clicks "Enter VR" (a user gesture), waits for frames
        page.evaluate("xr.controllers.right.position.set(0, 1.2, -0.45)")
"""
from __future__ import annotations

import shutil
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

REPO = Path(__file__).resolve().parents[2]
IWER = REPO / "node_modules" / "iwer" / "build" / "iwer.min.js"
CHROMIUM_ARGS = [
    # WebGL2 without a GPU
    "--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
    # root in a container; and no connection of the browser's own (the network is closed)
    "--no-sandbox", "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--no-first-run", "--disable-default-apps", "--mute-audio",
]
INSTALL_HINT = "`./dev test` installs it (Debian package chromium; npm package iwer from package-lock.json)"


def chromium_path() -> str:
    for name in ("chromium", "chromium-browser"):
        found = shutil.which(name)
        if found:
            return found
    raise RuntimeError(f"no chromium on this machine: {INSTALL_HINT}")


def iwer_script(device: str = "metaQuest3", stereo: bool = True) -> str:
    """iwer's runtime and a device installed over the browser's own navigator.xr (`window.xr`)."""
    if not IWER.exists():
        raise RuntimeError(f"{IWER} is missing: {INSTALL_HINT}")
    return (IWER.read_text() + f"\n;window.xr = new IWER.XRDevice(IWER.{device});"
            f"xr.stereoEnabled = {'true' if stereo else 'false'};xr.installRuntime({{forceInstall: true}});")


@contextmanager
def chromium(headless: bool = True) -> Iterator:
    """A playwright Browser on Debian's chromium."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium_path(), args=CHROMIUM_ARGS, headless=headless)
        try:
            yield browser
        finally:
            browser.close()


def context_options(width: int = 640, height: int = 360, ignore_https_errors: bool = False) -> dict:
    """Browser context options for the page: its size, and leave to playwright's waiting helpers the
    string evaluation that the page's Content-Security-Policy forbids (the page never evaluates strings)."""
    return {"viewport": {"width": width, "height": height}, "ignore_https_errors": ignore_https_errors,
            "bypass_csp": True}


def headset_page(browser, url: str, width: int = 640, height: int = 360, ignore_https_errors: bool = False):
    """A new page with an emulated Quest 3 (its two eyes side by side), opened at `url`."""
    context = browser.new_context(**context_options(width, height, ignore_https_errors))
    context.add_init_script(iwer_script())
    page = context.new_page()
    page.goto(url)
    return page


def wait_connected(page, timeout_s: float = 20.0) -> None:
    page.wait_for_function("window.touch4d && touch4d.connected && touch4d.setup !== null", timeout=timeout_s * 1000)


def enter_vr(page, frames: int = 3, timeout_s: float = 30.0) -> None:
    """Click "Enter VR" as a user would, and wait until the session has drawn `frames` frames."""
    wait_connected(page, timeout_s)
    page.click("#enter-vr", timeout=timeout_s * 1000)
    page.wait_for_function(f"touch4d.session !== null && touch4d.xrFrames >= {frames}", timeout=timeout_s * 1000)


class DelayRelay:
    """A TCP relay on loopback that holds every chunk `delay_s` in each direction, in order: a
    network's latency for a page and its server on one machine (this kernel has no netem).

        with DelayRelay(server_port, 0.15) as relay:     # 150 ms each way: a 300 ms round trip
            page.goto(f"http://127.0.0.1:{relay.port}/")
    """

    def __init__(self, target_port: int, delay_s: float, target_host: str = "127.0.0.1"):
        import asyncio
        import threading

        self.target, self.delay_s = (target_host, target_port), delay_s
        self.port = 0
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="delay-relay", daemon=True)
        self._server = None
        self._tasks: set = set()

    def __enter__(self) -> "DelayRelay":
        import asyncio

        self._thread.start()
        self._server = asyncio.run_coroutine_threadsafe(
            asyncio.start_server(self._connection, "127.0.0.1", 0), self._loop).result(10)
        self.port = self._server.sockets[0].getsockname()[1]
        return self

    def __exit__(self, *exc) -> None:
        import asyncio

        async def stop():
            self._server.close()
            for task in list(self._tasks):
                task.cancel()
        asyncio.run_coroutine_threadsafe(stop(), self._loop).result(10)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(10)

    async def _connection(self, reader, writer) -> None:
        import asyncio

        try:
            up_reader, up_writer = await asyncio.open_connection(*self.target)
        except OSError:
            writer.close()
            return
        for source, sink in ((reader, up_writer), (up_reader, writer)):
            task = asyncio.ensure_future(self._pipe(source, sink))
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)

    async def _pipe(self, reader, writer) -> None:
        """Each chunk read is written `delay_s` after it came, by a timer of its own: in order (one
        delay for all), and a chunk costs one callback, not a task's wake-ups (a class's worth of
        pages through one relay)."""
        import asyncio

        loop = asyncio.get_running_loop()

        def write(data: bytes) -> None:
            if not writer.is_closing():
                writer.write(data)
        try:
            while True:
                data = await reader.read(65536)
                if not data:
                    loop.call_at(loop.time() + self.delay_s, writer.close)
                    return
                loop.call_at(loop.time() + self.delay_s, write, data)
        except (ConnectionError, asyncio.CancelledError):
            writer.close()
