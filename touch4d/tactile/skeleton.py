"""The articulated glove: the glove's samples and motors bound to the hand's bones, placed by a joint set.

The glove file's hand (a palm and five capsule fingers) is the hand at rest, fingers straight. It
defines a rest joint set in WebXR's order and conventions (25 joints, each a pose whose -z runs
along its bone toward the finger tip and whose +y points out of the back of the hand, and a
radius): the wrist at the palm's proximal edge, each finger's joints along its capsule's axis at
the fractions of the glove file's `bones:` section (touch4d.tactile.bones). Every sample and motor
belongs to one bone (the palm, moved by the wrist joint; or the phalanx of the capsule it lies in)
and keeps its coordinates in that bone's joint frame, so a tracked joint set places each of them
where its bone is: one rigid transform per bone, applied to all of the bone's points at once.

A joint set of straight fingers at a pose gives exactly the rigid hand at that pose (tested to
1e-9), so the rigid hand is the special case. A bone may be longer or shorter than the glove's
(another person's hand): its points are stretched along it to fit (the palm along the wrist's
axis, by the wrist-to-middle-knuckle distance). A joint set of the
other hand (WebXR's `handedness`) is the glove's hand mirrored: every point's x in its bone frame
changes sign, so the glove's thumb samples stay on the thumb.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from touch4d.errors import Touch4dError
from touch4d.geometry import quaternion
from touch4d.messages import HandJoints

from touch4d.glovefile import Bones
from touch4d.hands import WEBXR_JOINTS as JOINTS, HandShape

from .bones import fractions as bone_fractions
from .hand import FINGER_NAMES, Hand

UNIT_TOLERANCE = 1e-3          # as touch4d.messages.hand: a tracker's float32 quaternion passes
_N2_LOW, _N2_HIGH = (1.0 - UNIT_TOLERANCE) ** 2, (1.0 + UNIT_TOLERANCE) ** 2
JOINT_INDEX = {name: i for i, name in enumerate(JOINTS)}
WRIST = JOINT_INDEX["wrist"]


def joint_prefix(finger: str) -> str:
    """The WebXR joint-name prefix of a glove finger ('little' is WebXR's 'pinky')."""
    return "thumb-" if finger == "thumb" else f"{'pinky' if finger == 'little' else finger}-finger-"


def finger_joints(finger: str) -> tuple[str, str, str, str]:
    """The four joints that bound a finger's three bones, base to tip (the thumb's start at its metacarpal)."""
    p = joint_prefix(finger)
    if finger == "thumb":
        return (f"{p}metacarpal", f"{p}phalanx-proximal", f"{p}phalanx-distal", f"{p}tip")
    return (f"{p}phalanx-proximal", f"{p}phalanx-intermediate", f"{p}phalanx-distal", f"{p}tip")


BONE_PARTS = {"thumb": ("metacarpal", "proximal", "distal")}
FINGER_PARTS = ("proximal", "intermediate", "distal")

# (bone name, finger or None, joint at its base, joint at its end): the palm (from the wrist to the
# middle finger's knuckle), then each finger's three bones base to tip. Points bound to a bone move
# with the joint at its base, stretched along the bone as far as its end moved from its rest length.
BONES: tuple[tuple[str, str | None, str, str], ...] = (
    ("palm", None, "wrist", "middle-finger-phalanx-proximal"),) + tuple(
    (f"{f}-{part}", f, finger_joints(f)[k], finger_joints(f)[k + 1])
    for f in FINGER_NAMES for k, part in enumerate(BONE_PARTS.get(f, FINGER_PARTS))
)
BONE_NAMES = tuple(b[0] for b in BONES)

# Finger shapes for trackers without hand tracking (scripted, desktop): the most each joint bends
# toward the palm at curl 1 (degrees, base to tip), and how far each finger turns away from the
# middle finger at spread 1 (degrees about the back-of-hand axis; negative: toward the thumb).
MAX_FLEX_DEG = {"thumb": (35.0, 55.0, 70.0), "index": (90.0, 100.0, 60.0), "middle": (90.0, 100.0, 60.0),
                "ring": (90.0, 100.0, 60.0), "little": (90.0, 100.0, 60.0)}
SPREAD_DEG = {"thumb": -25.0, "index": -10.0, "middle": 0.0, "ring": 8.0, "little": 18.0}

# A finger the glove file leaves out still has joints (WebXR always has 25): the default glove's.
_DEFAULT_FINGERS = {
    "thumb": ((0.04, -0.02), 60.0, 0.074, 0.011), "index": ((0.035, 0.0475), 0.0, 0.075, 0.009),
    "middle": ((0.015, 0.0475), 0.0, 0.083, 0.009), "ring": ((-0.005, 0.0475), 0.0, 0.077, 0.009),
    "little": ((-0.025, 0.0475), 0.0, 0.062, 0.008),
}
_METACARPAL_AT = 0.15    # a finger's metacarpal joint: this fraction of the way from the wrist to its knuckle


class JointsError(Touch4dError, ValueError):
    """A joint set that cannot place the hand: names the field (names, positions, ...) and the problem."""


@dataclass(frozen=True)
class JointSet:
    """A hand's joints in screen coordinates (WebXR order and axes; positions and radii in screen units)."""

    names: tuple[str, ...]
    positions: np.ndarray       # (25, 3)
    orientations: np.ndarray    # (25, 4) unit quaternions x, y, z, w, joint -> screen
    radii: np.ndarray           # (25,)
    handedness: str

    def message(self, stamp: float = 0.0) -> HandJoints:
        """As the `hand/joints` message a tracker publishes (stamped `stamp`; 0: at publishing)."""
        return HandJoints(handedness=self.handedness, names=list(self.names), positions=self.positions,
                          orientations=self.orientations, radii=self.radii, valid=True, stamp=stamp,
                          source_stamp=stamp)

    def to_json(self) -> dict:
        return {"handedness": self.handedness, "names": list(self.names), "positions": self.positions.tolist(),
                "orientations": self.orientations.tolist(), "radii": self.radii.tolist()}


def _joint_frame(direction: np.ndarray) -> np.ndarray:
    """The rest frame (columns x, y, z in the hand frame) of a joint whose bone runs along `direction`
    in the palm's plane: -z along the bone, +y out of the back of the hand (+z of the hand frame)."""
    z = -direction / np.linalg.norm(direction)
    y = np.array([0.0, 0.0, 1.0]) - z[2] * z
    y /= np.linalg.norm(y)
    return np.column_stack([np.cross(y, z), y, z])


def _rot_x(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rot_y(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


class Skeleton:
    """The glove's rest joint set (hand frame, metres) and its samples and motors bound to bones."""

    def __init__(self, hand: Hand, bones: Bones, samples: np.ndarray, motor_positions: np.ndarray,
                 motor_sample: np.ndarray, units_per_metre: float = 4.0):
        self.units_per_metre = float(units_per_metre)     # the glove's scale, at which points are kept
        fingers = {f.name: f for f in hand.fingers}
        thumb = fingers.get("thumb")
        # The glove's hand is a left hand when its thumb lies at +x (x = y cross z, y along the
        # fingers, z out of the back), as WebXR's joint frames of a left hand have it.
        self.handedness = "left" if thumb is None or thumb.tip[0] >= 0 else "right"
        wrist = np.array([*(bones.wrist if bones.wrist is not None else (0.0, -hand.palm_half[1])), 0.0])

        positions = np.zeros((len(JOINTS), 3))
        frames = np.zeros((len(JOINTS), 3, 3))
        radii = np.zeros(len(JOINTS))
        positions[WRIST], radii[WRIST] = wrist, hand.palm_half[2]
        frames[WRIST] = _joint_frame(np.array([0.0, 1.0, 0.0]))
        self.fractions = {}
        for name in FINGER_NAMES:
            if name in fingers:
                f = fingers[name]
                base, tip, radius = f.base, f.tip, f.radius
            else:
                (bx, by), angle, length, radius = _DEFAULT_FINGERS[name]
                base = np.array([bx, by, 0.0])
                tip = base + length * np.array([math.sin(math.radians(angle)), math.cos(math.radians(angle)), 0.0])
            fractions = np.asarray(bone_fractions(bones, name))
            self.fractions[name] = fractions
            frame = _joint_frame(tip - base)
            at = np.r_[0.0, np.cumsum(fractions)]
            at[-1] = 1.0
            for k, joint in enumerate(finger_joints(name)):
                j = JOINT_INDEX[joint]
                positions[j] = base + at[k] * (tip - base)
                frames[j], radii[j] = frame, radius
            if name != "thumb":
                j = JOINT_INDEX[f"{joint_prefix(name)}metacarpal"]
                start = np.array([base[0], wrist[1] + _METACARPAL_AT * (base[1] - wrist[1]), 0.0])
                positions[j], frames[j], radii[j] = start, _joint_frame(base - start), radius
        self.rest_positions = positions
        self.rest_frames = frames
        self.rest_orientations = Rotation.from_matrix(frames).as_quat(canonical=True)
        self.radii = radii

        self.bone_joint = np.array([JOINT_INDEX[b[2]] for b in BONES])
        self.bone_end = np.array([JOINT_INDEX[b[3]] for b in BONES])
        self.rest_lengths = np.linalg.norm(positions[self.bone_end] - positions[self.bone_joint], axis=1)
        self._inv_rest2 = 1.0 / (self.units_per_metre * self.rest_lengths) ** 2

        self.sample_bone = self.bone_of(hand, samples)
        self.sample_local = self.local(samples, self.sample_bone)
        self.motor_bone = self.sample_bone[np.asarray(motor_sample, dtype=int)]
        self.motor_local = self.local(motor_positions, self.motor_bone)
        # local coordinates in screen units for placing (each bone's map is then a rotation)
        self._placing = {"samples": (np.ascontiguousarray(self.sample_local * self.units_per_metre), self.sample_bone),
                         "motors": (np.ascontiguousarray(self.motor_local * self.units_per_metre), self.motor_bone)}
        self._names_cache: tuple[list, np.ndarray | None] = ([], None)

    @classmethod
    def of(cls, glove) -> "Skeleton":
        return cls(glove.hand, glove.bones, glove.samples, glove.motor_positions, glove.motor_sample,
                   glove.units_per_metre)

    # ---- binding ------------------------------------------------------------------------------------
    def bone_of(self, hand: Hand, points: np.ndarray) -> np.ndarray:
        """The bone (index into BONES) of each hand-frame point (N, 3): the palm for a point in the
        palm, else the phalanx of the finger capsule nearest to it, by where it lies along the axis."""
        points = np.asarray(points, dtype=float)
        bone = np.zeros(len(points), dtype=int)
        best = np.full(len(points), np.inf)
        palm = hand.in_palm(points)
        for f in hand.fingers:
            axis = f.tip - f.base
            t = np.clip((points - f.base) @ axis / (axis @ axis), 0.0, 1.0)
            gap = np.linalg.norm(points - (f.base + t[:, None] * axis), axis=1) - f.radius
            closer = ~palm & (gap < best)
            part = np.searchsorted(np.cumsum(self.fractions[f.name])[:-1], t, side="right")
            first = BONE_NAMES.index(f"{f.name}-{BONE_PARTS.get(f.name, FINGER_PARTS)[0]}")
            bone = np.where(closer, first + part, bone)
            best = np.where(closer, gap, best)
        return bone

    def local(self, points: np.ndarray, bone: np.ndarray) -> np.ndarray:
        """Hand-frame points (N, 3), metres, in the rest frames of their bones' base joints."""
        j = self.bone_joint[bone]
        return np.einsum("nji,nj->ni", self.rest_frames[j], np.asarray(points, float) - self.rest_positions[j])

    # ---- joint sets ---------------------------------------------------------------------------------
    def joint_set(self, position, orientation, units_per_metre: float, shape: HandShape | None = None,
                  handedness: str | None = None) -> JointSet:
        """The glove's hand at a pose (screen position, unit quaternion hand -> screen), its fingers
        bent as `shape` says (default straight), as the joint set a hand tracker would publish; as
        the other hand (`handedness`), the glove's mirrored in the hand frame's x."""
        positions, frames = self.shaped(shape) if shape is not None else (self.rest_positions, self.rest_frames)
        handedness = handedness or self.handedness
        if handedness != self.handedness:
            # mirrored: x -> -x; each joint keeps -z along its bone and +y out of the back, so its
            # x axis turns round (a right-handed frame): columns -M x, M y, M z = M R M
            mirror = np.diag([-1.0, 1.0, 1.0])
            positions, frames = positions @ mirror, mirror @ frames @ mirror
        world = quaternion.to_matrix(quaternion.canonical(orientation))
        out_pos = np.asarray(position, dtype=float) + units_per_metre * positions @ world.T
        out_q = Rotation.from_matrix(world @ frames).as_quat(canonical=True)
        return JointSet(tuple(JOINTS), out_pos, out_q, self.radii * units_per_metre, handedness)

    def shaped(self, shape: HandShape) -> tuple[np.ndarray, np.ndarray]:
        """Joint positions (25, 3) and frames (25, 3, 3), hand frame, metres, with the fingers bent:
        each joint of a finger turns its bone toward the palm (about the joint's x axis), the
        finger's base turns sideways for the spread (about its y axis)."""
        positions, frames = self.rest_positions.copy(), self.rest_frames.copy()
        for name in FINGER_NAMES:
            chain = [JOINT_INDEX[j] for j in finger_joints(name)]
            curl = min(max(shape.of(name), 0.0), 1.0)
            spread = min(max(float(shape.spread), 0.0), 1.0) * SPREAD_DEG[name]
            frame = frames[chain[0]] @ _rot_y(spread)
            point = positions[chain[0]]
            lengths = self.fractions[name] * np.linalg.norm(positions[chain[-1]] - positions[chain[0]])
            for k in range(3):
                frame = frame @ _rot_x(-curl * MAX_FLEX_DEG[name][k])     # -z toward -y: toward the palm
                positions[chain[k]], frames[chain[k]] = point, frame
                point = point + frame @ np.array([0.0, 0.0, -lengths[k]])
            positions[chain[3]], frames[chain[3]] = point, frame
        return positions, frames

    # ---- placing the glove --------------------------------------------------------------------------
    def joint_indices(self, names) -> np.ndarray | None:
        """Where each of WebXR's 25 joints is in a message's `names` (None: already in WebXR's order)."""
        if len(names) == len(JOINTS) and names == self._names_cache[0]:
            return self._names_cache[1]
        if list(names) == list(JOINTS):
            index = None
        else:
            where = {n: i for i, n in enumerate(names)}
            missing = [n for n in JOINTS if n not in where]
            if missing:
                raise JointsError(f"names: expected WebXR's 25 joints, missing {', '.join(missing[:3])}"
                                  + (f" and {len(missing) - 3} more" if len(missing) > 3 else ""))
            index = np.array([where[n] for n in JOINTS])
        self._names_cache = (list(names), index)
        return index

    def transforms(self, names, positions, orientations, handedness: str, units_per_metre: float) -> np.ndarray:
        """Every bone's map (B, 3, 4) of its points' local coordinates (screen units at the glove's
        scale) to the screen, [linear | translation]; raises JointsError for joints that cannot be used.

        The tactile loop's hot path, compiled (touch4d.tactile.bone_kernels)."""
        index = self.joint_indices(names)
        p = np.asarray(positions, dtype=float)
        q = np.asarray(orientations, dtype=float)
        if p.shape != (len(names), 3) or q.shape != (len(names), 4):
            raise JointsError(f"positions, orientations: expected ({len(names)}, 3) and ({len(names)}, 4), "
                              f"got {p.shape} and {q.shape}")
        base, end = (self.bone_joint, self.bone_end) if index is None else (index[self.bone_joint], index[self.bone_end])
        m = np.empty((len(base), 3, 4))
        if not _kernels().bone_maps(p, q, base, end, self._inv_rest2, quaternion.QUADRATIC_FORM, _N2_LOW, _N2_HIGH,
                                      handedness != self.handedness, units_per_metre / self.units_per_metre, m):
            self._explain(p[base], p[end], q[base], np.sqrt(np.einsum("ij,ij->i", q[base], q[base])))
        return m

    def _explain(self, t, ends, q, norms) -> None:
        """Raise the JointsError that names the first joint that cannot be used."""
        for k, bone in enumerate(BONES):
            if not (np.isfinite(t[k]).all() and abs(norms[k] - 1.0) <= UNIT_TOLERANCE):
                raise JointsError(f"joint {bone[2]}: expected a finite position and a unit quaternion, got "
                                  f"{t[k].tolist()} and {q[k].tolist()}")
        for k, bone in enumerate(BONES):
            if not np.isfinite(ends[k]).all():
                raise JointsError(f"joint {bone[3]}: expected a finite position, got {ends[k].tolist()}")
        raise JointsError("positions: expected joints within a hand's reach of each other, got coordinates too "
                          "large to compute with")

    def warm_up(self) -> None:
        """Compile (or load from numba's cache) the kernels now, by placing the rest joint set: a
        loop's first joint set then costs what the others do."""
        rest = self.joint_set(np.zeros(3), quaternion.IDENTITY, self.units_per_metre)
        self.place("samples", self.transforms(rest.names, rest.positions, rest.orientations, rest.handedness,
                                              self.units_per_metre))

    def place(self, which: str, m: np.ndarray) -> np.ndarray:
        """The samples ("samples") or motors ("motors") in the screen, from `transforms`: each point
        through its own bone's map."""
        local, bone = self._placing[which]
        out = np.empty_like(local)
        _kernels().place_points(m, local, bone, out)
        return out


def _kernels():
    """touch4d.tactile.bone_kernels, imported at the first joint set: numba and LLVM cost a process
    some 100 MB, which the nodes that only hold a glove (a page's node, the study node) never need."""
    from . import bone_kernels
    return bone_kernels


def _outline_pairs() -> np.ndarray:
    pairs = []
    for name in FINGER_NAMES:
        p = joint_prefix(name)
        chain = [f"{p}metacarpal", *finger_joints(name)[1 if name == "thumb" else 0:]]
        chain = [JOINT_INDEX[c] for c in chain]
        pairs.append((WRIST, chain[0]))
        pairs += list(zip(chain, chain[1:]))
    knuckles = [JOINT_INDEX[finger_joints(n)[0]] for n in FINGER_NAMES[1:]]
    pairs += list(zip(knuckles, knuckles[1:]))
    return np.array(pairs)


OUTLINE_PAIRS = _outline_pairs()


def outline_segments(joint_positions: np.ndarray) -> np.ndarray:
    """Segments (S, 2, 3) between joints (WebXR order) that draw the hand's skeleton."""
    return np.asarray(joint_positions)[OUTLINE_PAIRS]


JOINTS_TIMEOUT_S = 0.05   # joint sets older than this against the poses are stale (the tactile node's default)


@dataclass(frozen=True)
class PlacedHand:
    """The hand as a view draws it: samples and outline in the screen, from joints or a pose."""

    source: str                  # "joints" or "pose"
    samples: np.ndarray          # (N, 3) screen
    outline: np.ndarray          # (S, 2, 3) segments, screen
    joints: np.ndarray | None    # (25, 3) the joints' positions (None for a pose)
    stamp: float


class ViewHand:
    """Which hand the views draw, by the tactile node's rule: the latest joint set while valid and
    no older than `timeout_s` against the latest pose, else the rigid pose. Bad joints are dropped
    (`on_joints` raises JointsError; the pose is drawn)."""

    def __init__(self, glove, timeout_s: float = JOINTS_TIMEOUT_S):
        self.glove = glove
        self.timeout_s = timeout_s
        self.joints: PlacedHand | None = None
        self.wrist_orientation: np.ndarray | None = None
        self.pose_stamp = -np.inf

    def on_joints(self, msg) -> PlacedHand | None:
        """Adopt a HandJoints message; the placed hand, or None when it is not valid."""
        self.joints = None
        if not msg.valid:
            return None
        g = self.glove
        m = g.skeleton.transforms(msg.names, msg.positions, msg.orientations, msg.handedness, g.units_per_metre)
        index = g.skeleton.joint_indices(msg.names)
        joints = np.asarray(msg.positions, float) if index is None else np.asarray(msg.positions, float)[index]
        self.joints = PlacedHand("joints", g.skeleton.place("samples", m), outline_segments(joints), joints,
                                 float(msg.stamp))
        q = np.asarray(msg.orientations, float)[0 if index is None else index[WRIST]]
        self.wrist_orientation = q / np.linalg.norm(q)
        return self.joints

    def on_pose(self, stamp: float) -> None:
        self.pose_stamp = float(stamp)

    def current(self) -> PlacedHand | None:
        """The joints' hand when it drives, else None (draw the pose)."""
        if self.joints is not None and self.pose_stamp <= self.joints.stamp + self.timeout_s:
            return self.joints
        return None
