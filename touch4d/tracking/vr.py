"""OpenVR data -> touch4d values, without importing openvr: poses from 3x4 matrices, buttons from masks.

The button ids are OpenVR's EVRButtonId values (openvr.h), stable across SDK versions.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from touch4d.geometry import quaternion

BUTTON_IDS = {"menu": 1, "grip": 2, "trackpad": 32, "trigger": 33}

MISSING_PACKAGE = (
    "openvr tracker: the Python package 'openvr' is not installed, so no SteamVR controller can be "
    "read. Install it with `pip install touch4d[vr]` (or `pip install openvr`) in touch4d's "
    "environment, start SteamVR with the headset and the controller switched on, and launch again. "
    "Without VR hardware, use tracker:=desktop (keyboard and mouse) or tracker:=scripted."
)

NO_STEAMVR = (
    "openvr tracker: SteamVR is not running or has no headset ({error}). Start SteamVR with the "
    "headset connected and the controller switched on, then launch again (the 'openvr' package comes "
    "with `pip install touch4d[vr]`). Without VR hardware, use tracker:=desktop or tracker:=scripted."
)


def pose_from_matrix(m34) -> tuple[np.ndarray, np.ndarray]:
    """An OpenVR HmdMatrix34_t (device -> tracking space, rows of 4) -> (position m, quaternion x,y,z,w)."""
    m = np.asarray(m34, dtype=float).reshape(3, 4)
    return m[:, 3].copy(), quaternion.canonical(Rotation.from_matrix(m[:, :3]).as_quat())


def buttons_from_mask(mask: int) -> list[str]:
    """The names of the buttons set in an `ulButtonPressed` bit mask (bit i = button id i)."""
    return [name for name, bit in BUTTON_IDS.items() if int(mask) >> bit & 1]
