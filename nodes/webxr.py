"""WebXR node: the 4D scene in a headset's browser (or a desktop browser), and the headset as the tracker.

Serves the page (touch4d/web/static) and a WebSocket to it; sends the page `scene/state`,
`hand/pose`, `tactile/field`, `tactile/motors` and `motors/status` (geometry once per change of
what the scene is made of, then per change only transforms and tactile values). With `tracker:
true` it publishes what the page tracks: `hand/pose` (screen coordinates, from the controller's
grip or from hand tracking: `hand_source`), `controller/state` and the tracked hands' joints
(`hand/joints`: the glove hand, which the tactile node follows; `hand/joints/other`: the other).
With `touch: page` the page computes the glove hand's touch itself (the renderer's ray per glove
sample, eq. 1-3, static/touch.js) and plays it in the frame it tracked the hand; what it played
comes back with its inputs and goes out here on `tactile/motors` (the tactile node then publishes
`tactile/field` alone: its `motors: false`).
The page draws the articulated hand while `hand/joints` drives. A running study (`study/trial`)
shows its question in the page, hides objects where its condition says so, and the page's answers
(controller buttons, or the page's own) go out on `study/response`.

Access: `host` 127.0.0.1 (default) serves this machine only (and a Quest over USB through `adb
reverse tcp:PORT tcp:PORT`); any other host requires a token (random, printed in the link and as a
QR code; or one of 128 bits or more from a file or the environment, never the command line, where
`ps` shows it) and serves https with a self-signed certificate made in `cert_dir` (`tls: auto`;
`tls: off` is refused beyond loopback: the token would cross the network in clear). The page trades
the link's token for a cookie on first load (touch4d.web.access).
"""
from __future__ import annotations

import os
from pathlib import Path

from touch4d.bus import Node, Param
from touch4d.deadline import Deadline
from touch4d.errors import ConfigError
from touch4d.messages import (ControllerState, HandJoints, HandPose, MotorCommand, MotorStatus, SceneState,
                              Stop, StudyResponse, StudyTrial, TactileField)
from touch4d.tactile.glove import load_glove
from touch4d.tracking.calibration import load_calibration, load_placement, save_screen_placement
from touch4d.tracking.webxr import HAND_SOURCES, HANDS, XR_STANDARD_BUTTONS
from touch4d.web import access, tls
from touch4d.study.gate import GATE_START
from touch4d.web.bridge import BridgeConfig, WebBridge
from touch4d.web.server import PageBounds, PageServer


TOKEN_ENV = "TOUCH4D_WEBXR_TOKEN"


class WebXRNode(Node):
    """Bridges topics and WebXR pages."""

    default_name = "webxr"
    PARAMS = {
        "host": Param("127.0.0.1", "address to serve on; beyond loopback: https and a token"),
        "port": Param(8090, "TCP port (0 = any free one)", min=0, max=65535, port=True),
        "token": Param("auto", f"auto (random, only beyond loopback), env (from ${TOKEN_ENV}) or file (token_file)",
                       choices=("auto", "env", "file")),
        "token_file": Param("", "with token: file, the file holding the token (128 bits or more)"),
        "secret_file": Param("", "a file holding a secret that every request but the page's files must carry in "
                             "the X-Touch4d-Secret header (the study server's, in front of a participant's page)"),
        "names": Param("", "host names served besides loopback and this machine's addresses (comma-separated), "
                       "e.g. the reverse proxy's public name"),
        "tls": Param("auto", "https: auto (beyond loopback), on, off (loopback only)", choices=("auto", "on", "off")),
        "cert_dir": Param("", "where the self-signed certificate is kept ('' = ~/.config/touch4d/webxr-tls)"),
        "tracker": Param(False, "publish what the page tracks (hand/pose, controller/state, hand/joints)"),
        "hand": Param("right", "the hand that wears the glove", choices=HANDS),
        "hand_source": Param("controller", "the glove hand's pose from the controller's grip or hand tracking",
                             choices=HAND_SOURCES),
        "controller_hand": Param("same", "the controller (or tracked hand) that turns the object: the glove's "
                                 "hand (same) or a side", choices=("same", *HANDS)),
        "recenter_button": Param("a", "the controller button that re-centres the screen",
                                 choices=tuple(b for b in XR_STANDARD_BUTTONS if b)),
        "calibration": Param("config/calibration.yaml", "room -> screen calibration (re-centring writes it)",
                             path="calibration file"),
        "save_calibration": Param(True, "store a re-centred screen in the calibration file"),
        "glove": Param("config/glove.yaml", "the glove file", path="glove file"),
        "rate": Param(90.0, "frames sent to the pages per second, at most", unit="Hz", above=0, max=240),
        "max_pages": Param(64, "pages connected at once; one more is refused (HTTP 503)", min=1, max=10000),
        "study_gate": Param("open", "before any study/trial: open (no study), closed (a study runs)",
                            choices=GATE_START),
        "touch": Param("node", "where the glove hand's touch is computed: node (the tactile node's tactile/motors, "
                       "played by the page a network round trip later) or page (the page's own tactile pass, played "
                       "in the frame it tracks, published here on tactile/motors; needs tracker: true)",
                       choices=("node", "page")),
        "framebuffer_scale": Param(1.0, "the headset's pixels drawn: the XR layer's framebufferScaleFactor (1: the "
                                   "browser's default resolution)", above=0, max=1),
        "foveation": Param(0.5, "fixed foveation of the XR layer where the browser has it (the Quest's): 0 none, "
                           "1 the most", min=0, max=1),
        "pacing": Param(True, "while the headset's frames run late, the page lowers framebuffer_scale and raises "
                        "foveation, step by step (and back when on time; docs/webxr.md)"),
        "stale_s": Param(0.06, "a tracker page silent this long: the hand is invalid (motors off)", unit="s",
                         above=0, max=0.09),
    }

    def setup(self) -> None:
        p = self.params
        host = p["host"]
        loopback = access.is_loopback(host)
        if p["tls"] == "off" and not loopback:
            raise self.param_error("tls", "auto or on beyond loopback (with tls off the token crosses the network "
                                          "in clear)", got="off")
        self.token = self._token(loopback)
        self.access = None
        if self.token is not None:
            self.access = access.Access()
            self.access.issue("page", token=self.token)
        ssl_context, fingerprint = None, None
        if p["tls"] == "on" or (p["tls"] == "auto" and not loopback):
            cert, key, fingerprint = tls.ensure_certificate(
                Path(p["cert_dir"]) if p["cert_dir"] else tls.DEFAULT_CERT_DIR, access.lan_addresses(host))
            ssl_context = tls.server_ssl_context(cert, key)

        if p["touch"] == "page" and not (p["tracker"] and p["hand_source"] == "controller"):
            raise self.param_error("touch", "node, or page with tracker: true and hand_source: controller (the page "
                                            "computes the touch of the controller it tracks in the glove hand)",
                                   got="page")
        config = BridgeConfig(touch=p["touch"], tracker=p["tracker"], hand=p["hand"], hand_source=p["hand_source"],
                              controller_hand=p["hand"] if p["controller_hand"] == "same" else p["controller_hand"],
                              recenter_button=p["recenter_button"], stale_s=p["stale_s"],
                              study_gate=p["study_gate"], frame_period_s=1.0 / p["rate"],
                              framebuffer_scale=p["framebuffer_scale"], foveation=p["foveation"], pacing=p["pacing"])
        self.publishers = {"study/response": self.create_publisher("study/response", StudyResponse)}
        if p["tracker"]:
            self.publishers |= {"hand/pose": self.create_publisher("hand/pose", HandPose),
                               "controller/state": self.create_publisher("controller/state", ControllerState),
                               "hand/joints": self.create_publisher("hand/joints", HandJoints),
                               "hand/joints/other": self.create_publisher("hand/joints/other", HandJoints)}
        if p["touch"] == "page":   # what the page played, for the log and the monitor
            self.publishers["tactile/motors"] = self.create_publisher("tactile/motors", MotorCommand)
        self.bridge = WebBridge(config, load_glove(p["glove"]), load_calibration(p["calibration"], "hand_in_grip"),
                                load_placement(p["calibration"]), publish=self._publish,
                                broadcast=lambda data, latest: self.server.broadcast(data, latest),
                                send=lambda conn, data: self.server.send(conn, data),
                                save_calibration=self._save_calibration)
        # The server runs on the executor's loop, on this node's thread (touch4d.bus.executor); its
        # events still reach the bridge as the node's calls, on the executor's next turn (one thread
        # runs the bridge). Each page's messages wait in its bounded inbox until then (server.deliver).
        # each page event, then the bridge's deadline re-armed
        connected, closed = self._then_schedule(self.bridge.connected), self._then_schedule(self.bridge.closed)
        deliver = self._then_schedule(lambda conn: self.server.deliver(conn))
        self.server = PageServer(host, p["port"], self.access, ssl_context,
                                 bounds=PageBounds(max_pages=p["max_pages"]),
                                 secret=self._secret(),
                                 loop=self.executor.asyncio_loop(serves_tls=ssl_context is not None),
                                 names=[n.strip() for n in p["names"].split(",") if n.strip()],
                                 on_connect=lambda conn: self.call_soon_threadsafe(connected, conn,
                                                                                   self.server.peer(conn)),
                                 on_message=self.bridge.page_message,
                                 on_pending=lambda conn: self.call_soon_threadsafe(deliver, conn),
                                 on_close=lambda conn: self.call_soon_threadsafe(closed, conn))
        # The bridge's work without an event (a change's frame, stale vibration or hand, invalid poses,
        # a placement to store) runs at its next deadline (WebBridge.next_due), re-armed after every
        # event, not on a timer at the frame rate: with pages sending at 72 Hz, a 90 Hz timer was a
        # second wake-up of the participant's process per input.
        self._deadline = Deadline(self.call_later, self.bridge.now, self._tick)
        for topic, msg_type, callback, optional in (
                ("scene/state", SceneState, self.bridge.on_scene, False),
                ("hand/pose", HandPose, self.bridge.on_hand_pose, False),
                ("hand/joints", HandJoints, self.bridge.on_hand_joints, True),
                ("tactile/field", TactileField, self.bridge.on_field, False),
                ("tactile/motors", MotorCommand, self.bridge.on_motors, False),
                ("motors/status", MotorStatus, self.bridge.on_status, False),
                ("study/trial", StudyTrial, self.bridge.on_trial, True),
                ("safety/stop", Stop, self.bridge.on_stop, True)):   # the page's output stops as the glove's
            self.create_subscription(topic, msg_type, self._then_schedule(callback), latest_only=True,
                                     optional=optional)
        self._schedule()
        try:
            bound = self.server.start()
        except OSError as exc:
            raise self.param_error("port", f"a port free on {host}", got=f"{p['port']} ({exc.strerror or exc})") \
                from None
        self.add_cleanup(self.server.stop)
        self.add_stats(lambda: {**self.bridge.counts, **self.server.counts(),
                                "pages": len(self.bridge.pages), "page_fps": round(self.bridge.page_fps(), 1),
                                "page_scale": round(self.bridge.page_scale(), 3),
                                **self.bridge.haptic_outputs()})
        self._announce(bound, loopback, ssl_context is not None, fingerprint)

    def _announce(self, bound: int, loopback: bool, secure: bool, fingerprint: str | None) -> None:
        """Say where the page is served (its links, the certificate's fingerprint, a QR code beyond loopback),
        or that a proxy serves it."""
        p = self.params
        host = p["host"]
        role = "tracker and view" if p["tracker"] else "view"
        if self.server.secret:   # behind a proxy (a study server): no one opens it here
            self.log.info("WebXR page (%s) served on 127.0.0.1:%d to the proxy holding its secret; its users "
                          "come through that proxy's links", role, bound)
            return
        scheme = "https" if secure else "http"
        urls = [access.page_url(scheme, a, bound, self.token)
                for a in (["127.0.0.1"] if loopback else access.lan_addresses(host))]
        for url in urls:
            self.log.info("WebXR page (%s, %s source): %s", role, p["hand_source"] if p["tracker"] else "scripted",
                          url)
        if fingerprint:
            self.log.info("TLS: self-signed certificate, SHA-256 %s (accept it once in the headset's browser)",
                          fingerprint)
        if not loopback:
            print(f"Open {urls[0]} in the headset's browser, or scan:\n{access.qr_text(urls[0])}", flush=True)
        else:
            self.log.info("Quest over USB: adb reverse tcp:%d tcp:%d, then open http://localhost:%d/ in its browser",
                          bound, bound, bound)

    def _token(self, loopback: bool) -> str | None:
        """The page's token: none on loopback unless given, random beyond it, or the user's own from the
        environment or a file (not a parameter's value: a command line is visible to every user)."""
        p = self.params
        if p["token"] == "auto":
            return None if loopback else access.new_token()
        if p["token"] == "env":
            token, where = os.environ.get(TOKEN_ENV, "").strip(), f"the environment variable {TOKEN_ENV}"
        else:
            if not p["token_file"]:
                raise self.param_error("token_file", "the file holding the token (with token: file)", got="")
            try:
                token = Path(p["token_file"]).expanduser().read_text().strip()
            except OSError as exc:
                raise self.param_error("token_file", "a readable file holding the token",
                                       got=f"{p['token_file']} ({exc.strerror or exc})") from None
            where = f"the token file {p['token_file']}"
        why = access.check_token(token) if token else "a token"
        if why is not None:
            raise self.param_error("token", f"in {where}: {why}", got=None)
        return token

    def _secret(self) -> str | None:
        """The proxy's secret from `secret_file` (None: none asked for); never logged."""
        path = self.params["secret_file"]
        if not path:
            return None
        try:
            secret = Path(path).read_text().strip()
        except OSError as exc:
            raise self.param_error("secret_file", "a readable file holding the secret",
                                   got=f"{path} ({exc.strerror or exc})") from None
        why = access.check_token(secret)
        if why is not None:
            raise self.param_error("secret_file", f"a secret in {path}: {why}", got=None)
        return secret

    def endpoints(self) -> dict[str, int]:
        server = getattr(self, "server", None)
        return {"page": server.port} if server is not None and server.port else {}

    def _then_schedule(self, callback):
        """`callback`, then the bridge's next deadline re-armed (it may have come nearer)."""
        def run(*args) -> None:
            try:
                callback(*args)
            finally:
                self._schedule()
        return run

    def _tick(self) -> None:
        try:
            self.bridge.tick()
        finally:
            self._schedule()

    def _schedule(self) -> None:
        """The one deadline at the bridge's next_due (touch4d.deadline: unless one as early stands)."""
        self._deadline.arm(self.bridge.next_due())

    def _publish(self, topic: str, msg) -> None:
        self.publishers[topic].publish(msg)

    def _save_calibration(self, calibration) -> None:
        path = self.params["calibration"]
        if not self.params["save_calibration"]:
            return
        try:
            save_screen_placement(path, calibration)
            self.log.info("screen re-centred at %s m, stored in %s", ", ".join(f"{v:.2f}" for v in calibration.center_m),
                          path)
        except (OSError, ConfigError) as exc:
            self.warn_once(("calibration", str(exc)), f"screen re-centred but not stored in {path}: {exc}")

    def on_shutdown(self) -> None:
        self.bridge.save_pending()                     # a re-centre still waiting for save_min_s
        if "hand/pose" in self.publishers:
            self.bridge.owner = None
            self.bridge.check_tracking(float("inf"))   # the hand leaves: motors off before the pages go


if __name__ == "__main__":   # python -m touch4d.nodes.NAME: run it, as `touch4d node run NAME` does
    from touch4d.bus.process import main_for_module

    main_for_module(__spec__.name)
