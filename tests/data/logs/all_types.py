"""The messages of `all_types.mcap`, written out by hand: one or more of every message type.

`all_types.mcap` was recorded from these values by the message code of its day (see
`make_all_types.py`); tests decode it with today's code and compare with the literals here, so a
change to the messages that stops old logs from reading (or reads them differently) fails.
Arrays are (dtype string, shape, values); NaN stands for itself.
"""
NAN = float("nan")
T = 1_700_000_000.0          # the stamps of the log
T_NS = 1_700_000_000_000_000_000


def arr(dtype: str, shape: tuple, values: list) -> tuple:
    return (dtype, shape, values)


# (topic, log time in ns, type, every field of the decoded message, header included)
def value(v):
    """A literal below as the value a node would put in a message (tuples made by `arr` become arrays)."""
    import numpy as np

    if isinstance(v, tuple):
        dtype, shape, values = v
        return np.array(values, dtype=dtype).reshape(shape)
    if isinstance(v, dict):
        return {k: value(x) for k, x in v.items()}
    if isinstance(v, list):
        return [value(x) for x in v]
    return v


MESSAGES = [
    ("hand/pose", T_NS + 1_000_000, "HandPose", {
        "stamp": T + 0.001, "seq": 0, "source_stamp": T + 0.001, "recorded_stamp": 0.0,
        "position": arr("<f8", (3,), [0.1, -0.2, 0.3]),
        "orientation": arr("<f8", (4,), [0.0, 0.0, 0.6, 0.8]), "valid": True}),
    ("hand/pose", T_NS + 2_000_000, "HandPose", {
        "stamp": T + 0.002, "seq": 1, "source_stamp": T + 0.002, "recorded_stamp": 0.0,
        "position": arr("<f8", (3,), [0.0, 0.0, 0.0]),
        "orientation": arr("<f8", (4,), [0.0, 0.0, 0.0, 1.0]), "valid": False}),
    # a message of a replay: re-stamped, its first recording's stamp kept in recorded_stamp
    ("hand/pose", T_NS + 3_000_000, "HandPose", {
        "stamp": T + 100.003, "seq": 2, "source_stamp": T + 100.0025, "recorded_stamp": T + 0.003,
        "position": arr("<f8", (3,), [0.25, 0.5, -0.75]),
        "orientation": arr("<f8", (4,), [0.0, 1.0, 0.0, 0.0]), "valid": True}),
    ("hand/joints", T_NS + 4_000_000, "HandJoints", {
        "stamp": T + 0.004, "seq": 0, "source_stamp": T + 0.004, "recorded_stamp": 0.0,
        "handedness": "left", "names": ["wrist", "thumb-metacarpal", "index-finger-tip"],
        "positions": arr("<f8", (3, 3), [[0.0, 0.0, 0.0], [0.01, 0.02, 0.03], [-0.5, 0.25, 0.125]]),
        "orientations": arr("<f8", (3, 4), [[0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.6, 0.8], [1.0, 0.0, 0.0, 0.0]]),
        "radii": arr("<f8", (3,), [0.02, 0.01, 0.005]), "valid": True}),
    ("controller/state", T_NS + 5_000_000, "ControllerState", {
        "stamp": T + 0.005, "seq": 0, "source_stamp": T + 0.005, "recorded_stamp": 0.0,
        "position": arr("<f8", (3,), [1.0, 2.0, 3.0]),
        "orientation": arr("<f8", (4,), [0.0, 0.0, 0.0, 1.0]), "trigger": 0.75, "buttons": ["menu", "grip"],
        "valid": True}),
    ("scene/state", T_NS + 6_000_000, "SceneState", {
        "stamp": T + 0.006, "seq": 0, "source_stamp": T + 0.006, "recorded_stamp": 0.0,
        "objects": [
            {"name": "cube", "shape": "tesseract", "params": {}, "size": 1.0,
             "position": arr("<f8", (4,), [0.0, 0.0, 0.0, 1.5]),
             "orientation": arr("<f8", (4, 4), [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0],
                                                [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]),
             "color": arr("<f8", (4,), [1.0, 0.5, 0.0, 1.0])},
            {"name": "ball", "shape": "sphere", "params": {"segments": 12, "radius": 0.5, "tags": ["a", "b"]},
             "size": 0.5, "position": arr("<f8", (4,), [0.5, -0.5, 0.0, 2.0]),
             "orientation": arr("<f8", (4, 4), [[0.0, -1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0],
                                                [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]),
             "color": arr("<f8", (4,), [0.0, 0.0, 1.0, 0.5])},
            {"name": "wedge", "shape": "custom", "params": {}, "size": 2.0,
             "position": arr("<f8", (4,), [0.0, 0.0, 0.0, 0.0]),
             "orientation": arr("<f8", (4, 4), [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0],
                                                [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]),
             "color": arr("<f8", (4,), [0.25, 0.25, 0.25, 1.0]),
             "parts": [arr("<f8", (5, 5), [[1.0, 0.0, 0.0, 0.0, 1.0], [0.0, 1.0, 0.0, 0.0, 1.0],
                                           [0.0, 0.0, 1.0, 0.0, 1.0], [0.0, 0.0, 0.0, 1.0, 1.0],
                                           [-1.0, -1.0, -1.0, -1.0, 0.0]]),
                       arr("<f8", (2, 5), [[0.0, 0.0, 0.0, 1.0, 3.0], [0.0, 0.0, 0.0, -1.0, -2.0]])]},
        ],
        "projection": "perspective", "eye_distance": 3.0, "selected": 2, "revision": 7,
        # fields added after the log was made: their defaults
        "view": "projection", "slice_w": 0.0, "slice_touch": "section"}),
    ("scene/command", T_NS + 7_000_000, "SceneCommand", {
        "stamp": T + 0.007, "seq": 0, "source_stamp": T + 0.007, "recorded_stamp": 0.0,
        "command": "projection", "argument": "toggle"}),
    ("tactile/field", T_NS + 8_000_000, "TactileField", {
        "stamp": T + 0.008, "seq": 0, "source_stamp": T + 0.001, "recorded_stamp": 0.0,
        "positions": arr("<f8", (4, 3), [[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0], [0.0, 0.0, 0.1]]),
        "l": arr("<f8", (4,), [0.1, NAN, 0.3, NAN]), "s": arr("<f8", (4,), [1.0, 0.0, 0.5, 0.0]),
        "h": arr("<f8", (4,), [1.0, 0.0, 0.25, 0.0]), "alpha": 2.0, "beta": 0.5, "gamma": 1.0}),
    # float32 arrays keep their dtype
    ("tactile/field", T_NS + 9_000_000, "TactileField", {
        "stamp": T + 0.009, "seq": 1, "source_stamp": T + 0.002, "recorded_stamp": 0.0,
        "positions": arr("<f4", (2, 3), [[0.5, 0.25, 0.125], [-0.5, -0.25, -0.125]]),
        "l": arr("<f4", (2,), [NAN, 0.5]), "s": arr("<f8", (2,), [0.0, 0.75]),
        "h": arr("<f8", (2,), [0.0, 0.5]), "alpha": 1.0, "beta": 0.25, "gamma": 0.5}),
    ("tactile/motors", T_NS + 10_000_000, "MotorCommand", {
        "stamp": T + 0.010, "seq": 0, "source_stamp": T + 0.001, "recorded_stamp": 0.0,
        "names": ["palm0", "palm1", "index_tip"], "intensity": arr("<f8", (3,), [0.0, 0.4, 1.0])}),
    ("motors/status", T_NS + 11_000_000, "MotorStatus", {
        "stamp": T + 0.011, "seq": 0, "source_stamp": T + 0.011, "recorded_stamp": 0.0,
        "boards": [{"id": 1, "online": True, "faults": [], "last_frame": T + 0.0105, "state": "operational"},
                   {"id": 2, "online": False, "faults": ["overcurrent", "timeout"], "last_frame": 0.0,
                    "state": "offline"}],
        "duty": arr("<f8", (3,), [0.0, 0.5, 0.25]), "bus_load": 0.21,
        "errors": {"send": 0, "bus_off": 1, "queue_full": 2}}),
    ("motors/trace", T_NS + 12_000_000, "MotorTrace", {
        "stamp": T + 0.012, "seq": 0, "source_stamp": T + 0.012, "recorded_stamp": 0.0,
        "source_stamps": arr("<f8", (2,), [T + 0.001, T + 0.002]),
        "frame_times": arr("<f8", (2,), [T + 0.0015, T + 0.0027])}),
    ("safety/stop", T_NS + 13_000_000, "Stop", {
        "stamp": T + 0.013, "seq": 0, "source_stamp": T + 0.013, "recorded_stamp": 0.0,
        "reason": "button pressed", "origin": "web"}),
    ("node/heartbeat", T_NS + 14_000_000, "Heartbeat", {
        "stamp": T + 0.014, "seq": 0, "source_stamp": T + 0.014, "recorded_stamp": 0.0,
        "node": "tactile", "pid": 4242, "kind": "tactile", "publishes": ["tactile/field", "tactile/motors"],
        "subscribes": ["hand/pose", "scene/state"], "stats": {"received": 3, "dropped": 0, "load": 0.125}}),
    ("ui/input", T_NS + 15_000_000, "InputEvents", {
        "stamp": T + 0.015, "seq": 0, "source_stamp": T + 0.015, "recorded_stamp": 0.0,
        "keys_down": ["w", "left_shift"], "pressed": ["space"], "mouse": arr("<f8", (2,), [640.0, 360.0]),
        "mouse_delta": arr("<f8", (2,), [1.5, -2.0]), "buttons": [1, 3], "scroll": -1.0}),
]
