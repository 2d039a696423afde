"""What is drawn around the scene: the screen's frame, the hand, the tactile cube (Fig. 17), the status line.

Pure numpy builders of vertex arrays (and a Pillow-drawn text image); the painter draws them.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from itertools import product

import numpy as np
from PIL import Image, ImageDraw, ImageFont

FRAME_COLOR = (0.75, 0.75, 0.8, 0.9)
MOTOR_COLOR = (0.0, 1.0, 1.0, 1.0)        # cyan, as in the paper's Fig. 17
MISS_COLOR = (0.45, 0.45, 0.5, 0.6)        # samples whose ray misses (l is NaN)
# The amplitude colour map (h = 0 dark blue, through purple, orange and yellow, to pale yellow at 1).
AMPLITUDE_STOPS = np.array([0.0, 0.25, 0.5, 0.75, 1.0])
AMPLITUDE_RGB = np.array([[0.15, 0.2, 0.45], [0.5, 0.2, 0.65], [0.95, 0.4, 0.25], [1.0, 0.75, 0.15],
                          [1.0, 1.0, 0.7]])


def amplitude_colors(h: np.ndarray) -> np.ndarray:
    """RGB (N, 3) for amplitudes h, clipped to 0..1."""
    h = np.clip(np.nan_to_num(np.asarray(h, dtype=float)), 0.0, 1.0)
    return np.stack([np.interp(h, AMPLITUDE_STOPS, AMPLITUDE_RGB[:, k]) for k in range(3)], axis=-1)


def amplitude_sizes(h: np.ndarray, small: float = 4.0, large: float = 13.0) -> np.ndarray:
    """Point sizes in pixels for amplitudes h."""
    h = np.clip(np.nan_to_num(np.asarray(h, dtype=float)), 0.0, 1.0)
    return small + (large - small) * h


def _cube_edges() -> np.ndarray:
    corners = np.array(list(product((-1.0, 1.0), repeat=3)))
    pairs = [(i, j) for i in range(8) for j in range(i + 1, 8) if np.sum(corners[i] != corners[j]) == 1]
    return corners[np.array(pairs)]                                    # (12, 2, 3)


CUBE_EDGES = _cube_edges()


def wire_cube(center, half: float, color=FRAME_COLOR) -> np.ndarray:
    """The 12 edges of an axis-aligned cube as line vertices (24, 7)."""
    pts = np.asarray(center, dtype=float) + half * CUBE_EDGES.reshape(-1, 3)
    return np.c_[pts, np.tile(color, (len(pts), 1))].astype(np.float32)


def screen_frame(color=FRAME_COLOR) -> np.ndarray:
    """The 3D screen [-1, 1]^3 as a wire cube."""
    return wire_cube((0.0, 0.0, 0.0), 1.0, color)


def points(positions: np.ndarray, rgba: np.ndarray, sizes) -> np.ndarray:
    """Point vertices (N, 8) from positions (N, 3), colours (N, 4) and sizes (N,) or a scalar."""
    positions = np.asarray(positions, dtype=float).reshape(-1, 3)
    sizes = np.broadcast_to(np.asarray(sizes, dtype=float), (len(positions),))
    return np.c_[positions, np.broadcast_to(rgba, (len(positions), 4)), sizes].astype(np.float32)


@dataclass(frozen=True)
class TactileCube:
    """Where the tactile cube sits beside the screen (screen units): centre and half edge."""

    center: tuple = (-2.1, 0.0, 0.0)
    half: float = 0.6

    def layout(self, local: np.ndarray) -> np.ndarray:
        """Place points (N, 3) (hand frame, any unit) in the cube: centred, scaled to fit with a margin."""
        local = np.asarray(local, dtype=float)
        if len(local) == 0:
            return local.reshape(0, 3)
        lo, hi = local.min(axis=0), local.max(axis=0)
        extent = float(np.max(hi - lo))
        scale = 0.9 * 2 * self.half / extent if extent > 0 else 1.0
        return (local - 0.5 * (lo + hi)) * scale + np.asarray(self.center)

    def geometry(self, local: np.ndarray, h: np.ndarray, l: np.ndarray | None = None,
                 motor_sample: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(line vertices, point vertices): the cube and a point per sample coloured and sized by h;
        samples driving a motor get a cyan ring (a larger cyan point under the sample's point)."""
        where = self.layout(local)
        h = np.asarray(h, dtype=float)
        rgba = np.c_[amplitude_colors(h), np.ones(len(h))]
        if l is not None:
            rgba[np.isnan(np.asarray(l, dtype=float))] = MISS_COLOR
        sizes = amplitude_sizes(h)
        parts = []
        if motor_sample is not None and len(motor_sample):
            m = np.asarray(motor_sample, dtype=int)
            m = m[(m >= 0) & (m < len(where))]
            parts.append(points(where[m], MOTOR_COLOR, sizes[m] + 5.0))
        parts.append(points(where, rgba, sizes))
        return wire_cube(self.center, self.half), np.concatenate(parts)


HAND_COLOR = (0.95, 0.85, 0.75, 0.9)


def hand_skeleton(hand) -> np.ndarray:
    """Segments (S, 2, 3) outlining a glove's hand in its own frame (metres): the palm box's edges
    and each finger's axis from base to tip."""
    palm = CUBE_EDGES * np.asarray(hand.palm_half)
    fingers = np.array([[f.base, f.tip] for f in hand.fingers]).reshape(-1, 2, 3)
    return np.concatenate([palm, fingers])


def hand_geometry(samples_screen: np.ndarray, origin, rotation: np.ndarray, h: np.ndarray | None = None,
                  skeleton_screen: np.ndarray | None = None, axis_length: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """(line vertices, point vertices) of the hand: its outline, its axes at the origin (x red,
    y green, z blue) and its sample points, coloured by the stimulus when a field for them is known."""
    origin = np.asarray(origin, dtype=float)
    axes = []
    for k, color in enumerate(((1, 0.3, 0.3, 1), (0.3, 1, 0.3, 1), (0.4, 0.5, 1, 1))):
        axes += [[*origin, *color], [*(origin + axis_length * rotation[:, k]), *color]]
    lines = [np.array(axes, np.float32)]
    if skeleton_screen is not None and len(skeleton_screen):
        seg = np.asarray(skeleton_screen, dtype=float).reshape(-1, 3)
        lines.append(np.c_[seg, np.tile(HAND_COLOR, (len(seg), 1))].astype(np.float32))
    if h is not None and len(h) == len(samples_screen):
        rgba = np.c_[amplitude_colors(h), np.full(len(h), 0.9)]
    else:
        rgba = HAND_COLOR
    return np.concatenate(lines), points(samples_screen, rgba, 4.0)


@lru_cache(maxsize=4)
def _font(size: int):
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow built without FreeType: the fixed bitmap font
        return ImageFont.load_default()


def text_image(lines: list[str], size: int = 14, color=(230, 230, 235, 255),
               background=(0, 0, 0, 150)) -> np.ndarray:
    """An RGBA image (H, W, 4) uint8 holding the text lines, for the status overlay."""
    font = _font(size)
    probe = ImageDraw.Draw(Image.new("RGBA", (1, 1)))
    boxes = [probe.textbbox((0, 0), line or " ", font=font) for line in lines]
    line_h = max(b[3] for b in boxes) + 4
    width = max(b[2] for b in boxes) + 12
    image = Image.new("RGBA", (width, line_h * len(lines) + 8), background)
    draw = ImageDraw.Draw(image)
    for i, line in enumerate(lines):
        draw.text((6, 4 + i * line_h), line, font=font, fill=color)
    return np.asarray(image)


def touched_motors(names: list[str], intensity: np.ndarray, threshold: float) -> list[str]:
    """Names of the motors driven above `threshold` (the glove's touch_threshold), strongest first."""
    intensity = np.asarray(intensity, dtype=float)
    order = np.argsort(-intensity, kind="stable")
    return [names[i] for i in order if intensity[i] > threshold]


PROMPT_SIZE = 22


def study_lines(trial, keys: list[str] | None = None) -> list[str]:
    """What a participant reads for a `study/trial` message: the question and the keys that answer it
    (`keys`, one per option; default 1, 2, ...) in a trial, else the line of its phase (break, pause,
    end); nothing between trials. The WebXR page shows the same lines with its controller's buttons."""
    if trial.phase == "stimulus":
        head = f"Trial {trial.index + 1} of {trial.total}" + (" (practice)" if trial.practice else "")
        labels = keys or [str(k) for k in range(1, len(trial.options) + 1)]
        answers = "   ".join(f"{key}: {option}" for key, option in zip(labels, trial.options))
        return [head, trial.prompt, answers]
    return [trial.message] if trial.message else []


def study_overlay(trial, below: np.ndarray | None = None) -> np.ndarray | None:
    """The study's lines in large type, above the status overlay `below` (if any)."""
    lines = study_lines(trial)
    if not lines:
        return below
    top = text_image(lines, size=PROMPT_SIZE, background=(0, 0, 0, 190))
    if below is None:
        return top
    width = max(top.shape[1], below.shape[1])
    out = np.zeros((top.shape[0] + below.shape[0], width, 4), np.uint8)
    out[:top.shape[0], :top.shape[1]] = top
    out[top.shape[0]:, :below.shape[1]] = below
    return out
