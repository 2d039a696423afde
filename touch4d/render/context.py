"""GL contexts and offscreen targets: headless EGL for tests, CLI and display-less nodes."""
from __future__ import annotations

import io
import os
from pathlib import Path

import moderngl
import numpy as np
from PIL import Image

from touch4d.atomic import write_atomic
from touch4d.errors import Touch4dError


class RenderError(Touch4dError):
    """No usable OpenGL context (no EGL / driver), or a rendering target could not be made."""


def create_headless_context() -> moderngl.Context:
    """An OpenGL 3.3+ context without a window, through EGL (Mesa llvmpipe on machines without a GPU)."""
    try:
        ctx = moderngl.create_context(standalone=True, backend="egl", require=330)
    except Exception as exc:  # moderngl/glcontext raise plain Exception subclasses per backend
        raise RenderError(f"cannot create a headless OpenGL 3.3 context through EGL: {exc}") from exc
    return ctx


class OffscreenTarget:
    """A colour + depth framebuffer of `size` (width, height) pixels; read back as a top-down RGBA image."""

    def __init__(self, ctx: moderngl.Context, size: tuple[int, int], samples: int = 0):
        width, height = int(size[0]), int(size[1])
        if width <= 0 or height <= 0:
            raise RenderError(f"frame size must be positive, got {width}x{height}")
        self.ctx = ctx
        self.size = (width, height)
        self.samples = samples
        self._color = ctx.renderbuffer(self.size, 4, samples=samples)
        self._depth = ctx.depth_renderbuffer(self.size, samples=samples)
        self.fbo = ctx.framebuffer([self._color], self._depth)
        if samples:
            # Multisampled frames are resolved into a plain framebuffer before reading.
            self._resolved_color = ctx.renderbuffer(self.size, 4)
            self._resolved = ctx.framebuffer([self._resolved_color])

    def use(self) -> None:
        self.fbo.use()
        self.ctx.viewport = (0, 0, *self.size)

    def read_rgba(self) -> np.ndarray:
        """The current frame as (height, width, 4) uint8, row 0 at the top."""
        source = self.fbo
        if self.samples:
            self.ctx.copy_framebuffer(self._resolved, self.fbo)
            source = self._resolved
        raw = source.read(components=4, alignment=1)
        return np.frombuffer(raw, dtype=np.uint8).reshape(self.size[1], self.size[0], 4)[::-1].copy()

    def release(self) -> None:
        for obj in (self.fbo, self._color, self._depth):
            obj.release()
        if self.samples:
            self._resolved.release()
            self._resolved_color.release()


def frame_files(output: str) -> str:
    """The file pattern (with `{frame}`) of numbered frames for the renderer's `output`: a pattern is
    kept, a folder (ending in "/" or existing) gets frame-NNNNNN.png, a file name gets -NNNNNN
    before its suffix; so frames are never written over one another."""
    if "{frame" in output:
        return output
    if output.endswith(("/", os.sep)) or Path(output).is_dir():
        return str(Path(output) / "frame-{frame:06d}.png")
    path = Path(output)
    return str(path.with_name(f"{path.stem}-{{frame:06d}}{path.suffix or '.png'}"))


def save_png(image: np.ndarray, path: str | Path) -> Path:
    """Write a (H, W, 4) uint8 image as PNG, creating the folder; the file appears whole (written
    beside it, then renamed: touch4d.atomic), so a reader never sees half a frame."""
    path = Path(path)
    png = io.BytesIO()
    Image.fromarray(image, "RGBA").save(png, format="PNG")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(path, png.getvalue(), durable=False)   # frames are made again at will: no fsync each
    except OSError as exc:
        raise RenderError(f"cannot write {path}: {exc.strerror or exc}") from exc
    return path
