"""Renderer node: draws `scene/state`, `hand/pose` or `hand/joints` (the articulated hand), `tactile/field`

With a display it opens a window (moderngl-window, glfw) with an orbit camera and publishes the
window's keyboard and mouse as `ui/input` for the desktop tracker. Without one (no DISPLAY, or
`headless: true`) it renders offscreen through EGL, where nobody sees it unless `output` saves the
frames: numbered PNGs, never one file written over (`frames/` -> frames/frame-000000.png, ...;
`shot.png` -> shot-000000.png, ...; or a pattern with `{frame}`), every `save_every`-th frame. A
message it cannot use is logged once per cause and counted; the last good state keeps being drawn.

Parameters: rate (frames/s), width, height, samples (MSAA), camera ("yaw=30,pitch=20,..."),
glove (file), headless, output, save_every (frames), max_frames (stop after; 0 = run on),
backend ("gpu": per-pixel ray test in shaders; "clip": the paper's clip units on the CPU; "auto":
gpu, or clip on a software rasteriser such as llvmpipe; gpu falls back to clip on a GL context that
cannot run it), fill_alpha, centre_alpha, clip,
show_frame, show_tactile, show_status.

A running study (`study/trial`) gates what is drawn (touch4d.study.gate: no object in a touch trial
or between trials) and puts its question and answer keys (1..9) at the top left.
"""
from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from touch4d.bus import Node, Param
from touch4d.errors import Touch4dError
from touch4d.messages import HandJoints, HandPose, InputEvents, MotorCommand, SceneState, StudyTrial, TactileField
from touch4d.render.backends import DEFAULT_BACKEND, backend_names
from touch4d.render.camera import OrbitCamera, parse_camera
from touch4d.render.context import RenderError, frame_files, save_png
from touch4d.render.frame import Style
from touch4d.render.hud import study_overlay
from touch4d.render.view import BACKGROUND, SceneView, Show
from touch4d.study.gate import GATE_START, StudyGate
from touch4d.tactile.glove import load_glove


class RendererNode(Node):
    """Keeps the last good state of every input and draws it at `rate`."""

    default_name = "renderer"
    PARAMS = {
        "rate": Param(60.0, "frames per second", unit="Hz", above=0),
        "width": Param(1024, "frame width", unit="pixels", min=16, max=8192),
        "height": Param(640, "frame height", unit="pixels", min=16, max=8192),
        "samples": Param(4, "MSAA samples (0 = none)", min=0),
        "camera": Param("", "orbit camera, e.g. 'yaw=30,pitch=20,distance=5'"),
        "glove": Param("config/glove.yaml", "the glove file", path="glove file"),
        "headless": Param(False, "render offscreen even with a display"),
        "backend": Param(DEFAULT_BACKEND, "how the 4D scene is drawn: gpu (per-pixel ray visibility in shaders), "
                         "clip (the paper's clip units, on the CPU), auto (gpu on a hardware GPU, else clip)",
                         choices=tuple(backend_names())),
        "view": Param("scene", "what is drawn: the scene's view, or projection, slice (each object's cross-section "
                      "at w = slice_w), both", choices=("scene", "projection", "slice", "both")),
        "slice_w": Param(None, "where the slice cuts (default: the scene's slice_w)", type=float),
        "output": Param("", "save frames as numbered PNGs: a folder/, a file.png or a pattern with {frame}"),
        "save_every": Param(1, "write every n-th frame", min=1),
        "max_frames": Param(0, "stop after this many frames (0 = run on)", min=0),
        "fill_alpha": Param(Style.fill_alpha, "opacity of the front cells' faces", min=0, max=1),
        "centre_alpha": Param(Style.centre_alpha, "opacity of the cell-centre copies", min=0, max=1),
        "clip": Param(True, "clip units (cells hidden behind others)"),
        "show_frame": Param(True, "draw the screen's frame"),
        "show_tactile": Param(True, "draw the hand's tactile field"),
        "show_status": Param(True, "draw the status text"),
        "study_gate": Param("open", "before any study/trial: open (no study), closed (a study runs)",
                            choices=GATE_START),
    }

    def setup(self) -> None:
        p = self.params
        rate, width, height, samples = p["rate"], p["width"], p["height"], p["samples"]
        backend = p["backend"]
        self.output = frame_files(p["output"]) if p["output"] else ""
        self.save_every, self.max_frames = p["save_every"], p["max_frames"]
        style = Style(fill_alpha=p["fill_alpha"], centre_alpha=p["centre_alpha"], clip=p["clip"])
        show = Show(frame=p["show_frame"], tactile=p["show_tactile"], status=p["show_status"])
        source, key = self.param_where("camera")
        self.camera = parse_camera(p["camera"], OrbitCamera(), f"{source}: {key}")
        self.view = SceneView(load_glove(p["glove"] or None), style, show,
                              view=None if p["view"] == "scene" else p["view"], slice_w=p["slice_w"])
        self.counts = {"frames": 0, "saved": 0, "scenes_built": 0, "bad_scenes": 0, "bad_poses": 0, "bad_fields": 0}
        self._received = {"scene": 0, "pose": 0, "field": 0, "motors": 0}
        self._rates = dict.fromkeys(self._received, 0.0)
        self._fps = 0.0
        self._rate_mark = (time.monotonic(), 0, dict(self._received))

        self.headless = p["headless"] or not os.environ.get("DISPLAY")
        self.window = None
        self.renderer = None
        self.input = None
        self.input_pub = None
        if self.headless:
            from touch4d.render.offscreen import OffscreenRenderer

            self.renderer = OffscreenRenderer((width, height), samples=samples, backend=backend, log=self.log)
            self.add_cleanup(self.renderer.release)
            self.backend = self.renderer.backend
            why = "headless: true" if p["headless"] else "no DISPLAY"
            if self.output:
                self.log.info("headless (%s): rendering offscreen through EGL at %g Hz with the %s backend, "
                              "every %sframe to %s, ...", why, rate, self.backend.name, _nth(self.save_every),
                              Path(self.output.format(frame=0)).absolute())
            else:
                self.log.warning(
                    "headless (%s): rendering offscreen, nothing is shown. To see the frames save them with "
                    "renderer.output:=frames/ (numbered PNGs; renderer.save_every:=%d keeps one a second), or "
                    "open a window: run with a display (or under xvfb-run -a)", why, max(1, round(rate)))
        else:
            from touch4d.render.backends import open_backend
            from touch4d.render.window import InputState, open_window

            self.input = InputState()
            try:
                self.window = open_window((width, height), self.camera, self.input, samples=samples)
            except (ValueError, RuntimeError) as exc:   # glfw: no display, no GL 3.3
                raise RenderError(f"cannot open a window on display {os.environ.get('DISPLAY')!r}: {exc}; "
                                  "set the parameter headless: true to render offscreen") from exc
            self.add_cleanup(self.window.destroy)
            self.backend = open_backend(backend, self.window.ctx, log=self.log)
            self.add_cleanup(self.backend.release)
            self.input_pub = self.create_publisher("ui/input", InputEvents)
            self.log.info("window %dx%d at %g Hz with the %s backend; publishing ui/input", width, height, rate,
                          self.backend.name)

        self.create_subscription("scene/state", SceneState, self.on_scene, latest_only=True)
        self.create_subscription("hand/pose", HandPose, self.on_pose, latest_only=True)
        self.create_subscription("hand/joints", HandJoints, self.on_joints, latest_only=True, optional=True)
        self.create_subscription("tactile/field", TactileField, self.on_field, latest_only=True)
        self.create_subscription("tactile/motors", MotorCommand, self.on_motors, latest_only=True)
        self.gate = StudyGate(p["study_gate"])
        self.create_subscription("study/trial", StudyTrial, self.gate.update, latest_only=True, optional=True)
        self.create_timer(1.0 / rate, self.on_frame)

    # ---- inputs: keep the last good state ----------------------------------------------------------
    def on_scene(self, msg: SceneState) -> None:
        self._received["scene"] += 1
        try:
            if self.view.set_scene(msg):
                self.counts["scenes_built"] += 1
        except Touch4dError as exc:   # MessageError, GeometryError: a scene that cannot be drawn
            self.counts["bad_scenes"] += 1
            self.warn_once(f"scene:{exc}", f"scene/state revision {msg.revision} cannot be drawn, "
                                            f"keeping the last good scene: {exc}")

    def on_pose(self, msg: HandPose) -> None:
        self._received["pose"] += 1
        try:
            self.view.set_hand(msg)
        except Touch4dError as exc:   # PoseError: a pose that cannot be placed
            self.counts["bad_poses"] += 1
            self.warn_once(f"pose:{exc}", f"hand/pose ignored: {exc}")

    def on_joints(self, msg: HandJoints) -> None:
        try:
            self.view.set_joints(msg)
        except Touch4dError as exc:   # JointsError: drawn as the rigid pose meanwhile
            self.counts["bad_joints"] = self.counts.get("bad_joints", 0) + 1
            self.warn_once(f"joints:{exc}", f"hand/joints not drawn: {exc}")

    def on_field(self, msg: TactileField) -> None:
        self._received["field"] += 1
        try:
            self.view.set_field(msg)
        except Touch4dError as exc:   # MessageError: a field that cannot be drawn
            self.counts["bad_fields"] += 1
            self.warn_once(f"field:{exc}", f"tactile/field ignored: {exc}")

    def on_motors(self, msg: MotorCommand) -> None:
        self._received["motors"] += 1
        self.view.set_motors(msg)

    # ---- drawing ------------------------------------------------------------------------------------
    def on_frame(self) -> None:
        self._update_rates()
        status = [f"renderer {self._fps:.0f} fps | scene {self._rates['scene']:.1f} Hz, "
                  f"pose {self._rates['pose']:.0f} Hz, field {self._rates['field']:.0f} Hz"]
        frame = self.study_frame(self.view.frame(status))
        if self.window is not None:
            if self.window.is_closing:
                self.request_shutdown()
                return
            self.window.use()
            size = self.window.buffer_size
            self.backend.paint(frame, self.camera.matrix(size), size, BACKGROUND)
            if self.output and self.counts["frames"] % self.save_every == 0:
                self._save(self._read_window(size))
            self.window.swap_buffers()          # also polls the window's events
            self.input_pub.publish(self.input.take())
        else:
            self.renderer.draw_frame(frame, self.camera)
            if self.output and self.counts["frames"] % self.save_every == 0:
                self._save(self.renderer.read())
        self.counts["frames"] += 1
        if self.max_frames and self.counts["frames"] >= self.max_frames:
            self.request_shutdown()

    def study_frame(self, frame):
        """A running study's gate and prompt: no object drawn where its condition hides them (the
        screen's frame and the hand stay), the question and its keys above the status."""
        if not self.gate.objects:
            frame.scene = None
        if self.gate.trial is not None:
            frame.overlay = study_overlay(self.gate.trial, frame.overlay)
        return frame

    def _read_window(self, size) -> np.ndarray:
        raw = self.window.ctx.screen.read(viewport=(0, 0, *size), components=4, alignment=1)
        return np.frombuffer(raw, dtype=np.uint8).reshape(size[1], size[0], 4)[::-1].copy()

    def _save(self, image) -> None:
        path = self.output.format(frame=self.counts["frames"])
        try:
            self._last_saved = save_png(image, Path(path)).absolute()
            self.counts["saved"] += 1
        except RenderError as exc:
            self.warn_once(f"save:{exc}", f"cannot write frame to {path}: {exc}")

    def _update_rates(self) -> None:
        now = time.monotonic()
        t0, frames0, received0 = self._rate_mark
        if now - t0 >= 1.0:
            self._fps = (self.counts["frames"] - frames0) / (now - t0)
            self._rates = {k: (self._received[k] - received0[k]) / (now - t0) for k in self._received}
            self._rate_mark = (now, self.counts["frames"], dict(self._received))

    def on_shutdown(self) -> None:
        self.log.info("drew %d frame(s): %s", self.counts["frames"], self.counts)
        if self.counts["saved"]:
            self.log.info("saved %d frame(s), the last %s", self.counts["saved"], self._last_saved)


def _nth(n: int) -> str:
    return "" if n == 1 else f"{n}th "


if __name__ == "__main__":   # python -m touch4d.nodes.NAME: run it, as `touch4d node run NAME` does
    from touch4d.bus.process import main_for_module

    main_for_module(__spec__.name)
