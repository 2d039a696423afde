"""WebXR node: the 4D scene in a headset's browser (or a desktop browser), and the headset as the tracker.

Serves the page (touch4d/web/static) and a WebSocket to it; sends the page `scene/state`,
`hand/pose`, `tactile/field`, `tactile/motors` and `motors/status` (geometry once per change of
what the scene is made of, then per tick only transforms and tactile values). With `tracker:
true` it publishes what the page tracks: `hand/pose` (screen coordinates, from the controller's
grip or from hand tracking: `hand_source`), `controller/state` and `hand/joints`.

Access: `host` 127.0.0.1 (default) serves this machine only (and a Quest over USB through `adb
reverse tcp:PORT tcp:PORT`); any other host requires the random token in the URL (printed, with a
QR code) and serves https with a self-signed certificate made in `cert_dir` (`tls: auto`).
Parameters: host, port, token ("auto" or a fixed one), tls ("auto", "on", "off"), cert_dir,
tracker, hand, hand_source, controller_hand, recenter_button, calibration, save_calibration,
glove, rate (page frames per second), stale_s (a silent tracker page's hand turns invalid).
"""
from __future__ import annotations

from pathlib import Path

from touch4d.bus import Node, run_node
from touch4d.errors import ConfigError
from touch4d.messages import ControllerState, HandJoints, HandPose, MotorCommand, MotorStatus, SceneState, TactileField
from touch4d.tactile.glove import load_glove
from touch4d.tracking.calibration import load_calibration, load_placement, save_screen_placement
from touch4d.tracking.config import positive_parameter
from touch4d.tracking.webxr import HAND_SOURCES, HANDS, XR_STANDARD_BUTTONS
from touch4d.web import access
from touch4d.web.bridge import BridgeConfig, WebBridge
from touch4d.web.server import PageServer

TLS_CHOICES = ("auto", "on", "off")


class WebXRNode(Node):
    """Bridges topics and WebXR pages; see the module doc for the parameters."""

    def __init__(self, **kwargs):
        super().__init__("webxr", **kwargs)
        self.server = None
        try:
            self._setup()
        except BaseException:
            self.shutdown()   # no socket, thread or port left behind by a bad parameter
            raise

    def _setup(self) -> None:
        source = self._params_source or f"parameters of node '{self.name}'"
        key = (lambda name: f"nodes.{self.name}.params.{name}") if self._params_source else (lambda name: name)
        host = self.declare_parameter("host", "127.0.0.1")
        port = self.declare_parameter("port", 8090)
        token = self.declare_parameter("token", "auto")
        tls = self.declare_parameter("tls", "auto")
        cert_dir = self.declare_parameter("cert_dir", "")
        tracker = self.declare_parameter("tracker", False)
        hand = self.declare_parameter("hand", "right")
        hand_source = self.declare_parameter("hand_source", "controller")
        controller_hand = self.declare_parameter("controller_hand", "") or hand
        recenter_button = self.declare_parameter("recenter_button", "a")
        calibration_file = self.declare_path_parameter("calibration", "config/calibration.yaml", "calibration file")
        self.save_calibration = self.declare_parameter("save_calibration", True)
        glove = self.declare_path_parameter("glove", "config/glove.yaml", "glove file")
        rate = positive_parameter(self.declare_parameter("rate", 90.0), source, key("rate"), 240.0, "Hz")
        stale_s = positive_parameter(self.declare_parameter("stale_s", 0.06), source, key("stale_s"), 0.09, "s")
        for name, value, choices in (("hand", hand, HANDS), ("controller_hand", controller_hand, HANDS),
                                     ("hand_source", hand_source, HAND_SOURCES), ("tls", tls, TLS_CHOICES),
                                     ("recenter_button", recenter_button, tuple(b for b in XR_STANDARD_BUTTONS if b))):
            if value not in choices:
                raise ConfigError(source, key(name), f"one of {', '.join(choices)}", got=value)
        if not 0 <= port <= 65535:
            raise ConfigError(source, key("port"), "a TCP port 0..65535 (0: any free one)", got=port)
        if not token:
            raise ConfigError(source, key("token"), "'auto' or a token of your own", got=token)

        loopback = access.is_loopback(host)
        self.token = None if token == "auto" and loopback else (access.new_token() if token == "auto" else token)
        ssl_context, fingerprint = None, None
        if tls == "on" or (tls == "auto" and not loopback):
            cert, key_file, fingerprint = access.ensure_certificate(
                Path(cert_dir) if cert_dir else access.DEFAULT_CERT_DIR, access.lan_addresses(host))
            ssl_context = access.server_ssl_context(cert, key_file)

        self.calibration_file = calibration_file
        config = BridgeConfig(tracker=tracker, hand=hand, hand_source=hand_source, controller_hand=controller_hand,
                              recenter_button=recenter_button, stale_s=stale_s)
        self.publishers = {}
        if tracker:
            self.publishers = {"hand/pose": self.create_publisher("hand/pose", HandPose),
                               "controller/state": self.create_publisher("controller/state", ControllerState),
                               "hand/joints": self.create_publisher("hand/joints", HandJoints)}
        self.server = PageServer(host, port, self.token, ssl_context,
                                 on_connect=lambda conn: self.call_soon_threadsafe(self.bridge.connected, conn),
                                 on_message=lambda conn, data, arrival: self.call_soon_threadsafe(
                                     self.bridge.page_message, conn, data, arrival),
                                 on_close=lambda conn: self.call_soon_threadsafe(self.bridge.closed, conn))
        self.bridge = WebBridge(config, load_glove(glove), load_calibration(calibration_file, "hand_in_grip"),
                                load_placement(calibration_file), publish=self._publish,
                                broadcast=self.server.broadcast, send=self.server.send,
                                save_calibration=self._save_calibration)
        self.create_subscription("scene/state", SceneState, self.bridge.on_scene, latest_only=True)
        self.create_subscription("hand/pose", HandPose, self.bridge.on_hand_pose, latest_only=True)
        self.create_subscription("tactile/field", TactileField, self.bridge.on_field, latest_only=True)
        self.create_subscription("tactile/motors", MotorCommand, self.bridge.on_motors, latest_only=True)
        self.create_subscription("motors/status", MotorStatus, self.bridge.on_status, latest_only=True)
        self.create_timer(1.0 / rate, self.bridge.tick)
        try:
            bound = self.server.start()
        except OSError as exc:
            raise ConfigError(source, key("port"), f"a port free on {host}", got=f"{port} ({exc.strerror or exc})") from None
        scheme = "https" if ssl_context else "http"
        urls = [access.page_url(scheme, a, bound, self.token)
                for a in (["127.0.0.1"] if loopback else access.lan_addresses(host))]
        role = "tracker and view" if tracker else "view"
        for url in urls:
            self.log.info("WebXR page (%s, %s source): %s", role, hand_source if tracker else "scripted", url)
        if fingerprint:
            self.log.info("TLS: self-signed certificate, SHA-256 %s (accept it once in the headset's browser)",
                          fingerprint)
        if not loopback:
            print(f"Open {urls[0]} in the headset's browser, or scan:\n{access.qr_text(urls[0])}", flush=True)
        else:
            self.log.info("Quest over USB: adb reverse tcp:%d tcp:%d, then open http://localhost:%d/ in its browser",
                          bound, bound, bound)

    def _publish(self, topic: str, msg) -> None:
        self.publishers[topic].publish(msg)

    def _save_calibration(self, calibration) -> None:
        if not self.save_calibration:
            return
        try:
            save_screen_placement(self.calibration_file, calibration)
            self.log.info("screen re-centred at %s m, stored in %s",
                          ", ".join(f"{v:.2f}" for v in calibration.center_m), self.calibration_file)
        except (OSError, ConfigError) as exc:
            self.log.warning("screen re-centred but not stored in %s: %s", self.calibration_file, exc)

    def stats_flat(self) -> dict:
        out = super().stats_flat()
        if self.server is not None:
            out.update(self.bridge.counts, page_refused=self.server.refused, pages=len(self.bridge.pages),
                       page_fps=round(self.bridge.page_fps(), 1))
        return out

    def on_shutdown(self) -> None:
        if self.server is None or not hasattr(self, "bridge"):
            return
        if self.publishers:
            self.bridge.owner = None
            self.bridge.check_tracking(float("inf"))   # the hand leaves: motors off before the pages go
        self.server.stop()


def main(argv=None):
    return run_node(WebXRNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
