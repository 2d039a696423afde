"""The stimulus of a hand on a tilted tesseract, worked by hand from the paper's equations, to check
the tactile code against (test_tactile_node, test_tactile_probe).

The scene: a tesseract of size 1.2 at (0, 0, 0, 1.6), turned -20 degrees in the xw plane. Its front
cell (local w = -0.6) becomes, with c = cos 20 and t = tan 20, the hyperplane
    w = 1.6 - 0.6 c - t (x + 0.6 sin 20)        for x in [-0.6 (c + sin 20), 0.6 (c - sin 20)],
so a ray along +w from a screen point (x, y, z), |y|, |z| <= 0.6, meets it at l = that w (eq. 4-7).
"""
import numpy as np

SCENE_YAML = """
projection: orthographic
objects:
  - name: cube
    shape: tesseract
    size: 1.2
    position: [0, 0, 0, 1.6]
    rotation: [[xw, -20]]
"""
UNITS_PER_METRE = 4.0          # the default glove: a 0.5 m screen is 2 units wide


def depth(x):
    """l for screen points with coordinate x on the front cell."""
    a = np.radians(20.0)
    x = np.asarray(x, dtype=float)
    assert np.all((x > -0.6 * (np.cos(a) + np.sin(a))) & (x < 0.6 * (np.cos(a) - np.sin(a)))), "off the front cell"
    return 1.6 - 0.6 * np.cos(a) - np.tan(a) * (x + 0.6 * np.sin(a))


def stimulus(glove_samples_m, hand, alpha, beta, gamma, motor_sample):
    """(positions, l, s, h, V) for the hand at `hand` (identity orientation): eq. 1, 2, 3."""
    positions = np.asarray(hand, dtype=float) + UNITS_PER_METRE * np.asarray(glove_samples_m)
    l = depth(positions[:, 0])
    s = np.maximum(1.0 - alpha * (l - l.min()), 0.0)                 # eq. 1
    h = (1.0 - beta * s[s > 0].mean()) * s                           # eq. 2
    return positions, l, s, h, gamma * h[motor_sample]              # eq. 3
