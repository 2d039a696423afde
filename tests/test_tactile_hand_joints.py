"""The articulated glove: samples and motors on the hand's bones, placed by a WebXR joint set.

Closed forms and independent constructions: the rigid hand's stimulus (a straight hand), the
mirror image (the other hand), distances that a rigid bone keeps, and boxes whose faces lie where
a curled finger or a fist's knuckles must (or must not) reach.
"""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from touch4d.errors import ConfigError
from touch4d.geometry.scene import Scene, SceneObject
from touch4d.tactile.glove import glove_from_dict, load_glove
from touch4d.hands import HandShape
from touch4d.tactile.skeleton import BONE_NAMES, BONES, JOINTS, JointsError
from touch4d.tactile.stimulus import compute_joint_stimulus, compute_stimulus
from touch4d.configfile import read_yaml, resolve_path

UPM = 4.0     # screen units per metre of the default glove


@pytest.fixture(scope="module")
def glove():
    return load_glove()


def box_scene(center, size, tilt_deg=0.0):
    """A tesseract whose projection is the cube `center` +- size / 2 (orthographic), its front cell
    tilted `tilt_deg` in the xw plane (so l varies across the hand) when asked."""
    from touch4d.geometry.rotation import rotation_from_list
    obj = SceneObject(name="box", shape="tesseract", size=size, position=np.array([*center, 2.0]),
                      orientation=rotation_from_list([["xw", tilt_deg]] if tilt_deg else []),
                      color=np.array([1.0, 1.0, 1.0, 1.0]))
    return Scene(objects=[obj], projection="orthographic")


def joint_stimulus(glove, caster, joints):
    return compute_joint_stimulus(glove, caster, joints.names, joints.positions, joints.orientations,
                                  joints.handedness)


def motor(glove, name):
    return glove.motor_names.index(name)


@pytest.mark.parametrize("seed", range(4))
def test_a_straight_hand_joint_set_gives_the_rigid_hands_stimulus(glove, seed):
    rng = np.random.default_rng(seed)
    caster = box_scene((0.0, 0.0, 0.0), 1.2, tilt_deg=-20).ray_caster()
    position = rng.uniform(-0.3, 0.3, 3)
    turn = Rotation.from_euler("zyx", rng.uniform(-180, 180, 3), degrees=True)   # angles the generator picks
    q = turn.as_quat() if seed else np.array([0.0, 0.0, 0.0, 1.0])
    rigid = compute_stimulus(glove, caster, position, q)
    joints = glove.skeleton.joint_set(position, q, glove.units_per_metre)
    jointed = joint_stimulus(glove, caster, joints)
    assert rigid.touched.sum() > 20                      # the hand is in the object: a real comparison
    np.testing.assert_allclose(jointed.positions, rigid.positions, atol=1e-12)
    np.testing.assert_array_equal(jointed.touched, rigid.touched)
    for name in ("l", "s", "h"):
        np.testing.assert_allclose(getattr(jointed, name), getattr(rigid, name), atol=1e-9, equal_nan=True)
    np.testing.assert_allclose(jointed.V, rigid.V, atol=1e-9)


def test_the_joint_set_is_webxrs_and_its_axes_follow_the_bones(glove):
    joints = glove.skeleton.joint_set([0, 0, 0], [0, 0, 0, 1], UPM)
    assert joints.names == JOINTS and len(JOINTS) == 25 and joints.handedness == "left"
    p = dict(zip(joints.names, joints.positions))
    # the index finger's capsule: base (0.035, 0.0475), 0.075 m along +y; its tip joint at the tip
    np.testing.assert_allclose(p["index-finger-phalanx-proximal"], np.array([0.035, 0.0475, 0]) * UPM, atol=1e-12)
    np.testing.assert_allclose(p["index-finger-tip"], np.array([0.035, 0.1225, 0]) * UPM, atol=1e-12)
    np.testing.assert_allclose(p["wrist"], [0, -0.0475 * UPM, 0], atol=1e-12)
    for name, q in zip(joints.names, joints.orientations):
        r = Rotation.from_quat(q).as_matrix()
        np.testing.assert_allclose(r[:, 1], [0, 0, 1], atol=1e-12)       # +y out of the back of the hand
    r = Rotation.from_quat(joints.orientations[JOINTS.index("thumb-phalanx-proximal")]).as_matrix()
    np.testing.assert_allclose(-r[:, 2], [np.sin(np.radians(60)), np.cos(np.radians(60)), 0], atol=1e-12)


def test_curling_the_index_out_of_an_object_turns_its_motors_off_while_the_palms_stay(glove):
    # The box spans z in [-0.06, 0.94]: the straight hand (0.1 units thick) is inside; a curled
    # index bends toward -z (the palm's side), 0.14 units and more past the knuckle.
    caster = box_scene((0.0, 0.0, 0.44), 1.0).ray_caster()
    where = [0.0, -0.1, 0.0]
    index = [i for i, n in enumerate(glove.motor_names) if n.startswith("index-")]
    palm = [i for i, n in enumerate(glove.motor_names) if n.startswith(("palm-", "back-"))]
    flat = joint_stimulus(glove, caster, glove.skeleton.joint_set(where, [0, 0, 0, 1], UPM))
    assert np.all(flat.V[index] > 0.3) and np.all(flat.V[palm] > 0.3)
    curled = joint_stimulus(glove, caster, glove.skeleton.joint_set(where, [0, 0, 0, 1], UPM,
                                                                   HandShape(curl={"index": 1.0})))
    np.testing.assert_array_equal(curled.V[index], 0.0)
    assert np.all(curled.V[palm] > 0.3)
    others = [i for i, n in enumerate(glove.motor_names) if n.startswith(("middle-", "ring-", "little-"))]
    assert np.all(curled.V[others] > 0.3)


def test_a_fist_touches_only_with_its_knuckles(glove):
    # A box whose lower face is at y = 0.2, just above the palm's edge (0.0475 m = 0.19 units): the
    # straight fingers reach far into it, a fist only with the backs of its proximal phalanges.
    caster = box_scene((0.0, 1.2, 0.0), 2.0).ray_caster()
    fist = HandShape(curl={f: 1.0 for f in ("thumb", "index", "middle", "ring", "little")})
    st = joint_stimulus(glove, caster, glove.skeleton.joint_set([0, 0, 0], [0, 0, 0, 1], UPM, fist))
    bones = {BONE_NAMES[b] for b in glove.skeleton.sample_bone[st.touched]}
    assert bones == {"index-proximal", "middle-proximal", "ring-proximal", "little-proximal"}
    assert st.positions[st.touched, 1].min() >= 0.2
    on = {glove.motor_names[i] for i in np.flatnonzero(st.V > 0)}
    assert on == {f"{f}-back-proximal" for f in ("index", "middle", "ring", "little")}
    flat = joint_stimulus(glove, caster, glove.skeleton.joint_set([0, 0, 0], [0, 0, 0, 1], UPM))
    assert {"index-distal", "middle-intermediate"} <= {BONE_NAMES[b] for b in glove.skeleton.sample_bone[flat.touched]}


def test_each_motor_moves_with_its_bone(glove):
    sk = glove.skeleton
    shape = HandShape(curl={"thumb": 0.4, "index": 0.7, "middle": 0.2, "ring": 1.0, "little": 0.5}, spread=0.6)
    q = Rotation.from_euler("xyz", [20, -35, 50], degrees=True).as_quat()
    rest = sk.joint_set([0, 0, 0], [0, 0, 0, 1], UPM)
    bent = sk.joint_set([0.2, -0.1, 0.3], q, UPM, shape)

    def motors(js):
        return sk.place("motors", sk.transforms(js.names, js.positions, js.orientations, js.handedness, UPM))

    m0, m1 = motors(rest), motors(bent)
    rigid = Rotation.from_quat(q).apply(m0) + [0.2, -0.1, 0.3]      # where the straight hand would put them
    for k, name in enumerate(glove.motor_names):
        bone = sk.motor_bone[k]
        base, end = sk.bone_joint[bone], sk.bone_end[bone]
        # a bone is rigid: the motor keeps its distances to the bone's joints, whatever the bend
        for j in (base, end) if end >= 0 else (base,):
            assert np.isclose(np.linalg.norm(m1[k] - bent.positions[j]), np.linalg.norm(m0[k] - rest.positions[j]),
                              atol=1e-9), name
        moved = np.linalg.norm(m1[k] - rigid[k])
        if BONE_NAMES[bone] == "palm":
            assert moved < 1e-9, name                   # the palm follows the wrist
        else:
            assert moved > 0.01, name                   # the fingers' motors follow their bent fingers
    # one finger bent alone moves its motors only
    index_only = sk.joint_set([0, 0, 0], [0, 0, 0, 1], UPM, HandShape(curl={"index": 0.5}))
    moved = np.linalg.norm(motors(index_only) - m0, axis=1) > 1e-9
    index = {n for n in glove.motor_names if n.startswith("index-")}
    assert {n for n, m in zip(glove.motor_names, moved) if m} == index


def test_the_other_hand_is_the_glove_mirrored(glove):
    """A right hand's joint set (WebXR's axes: -z along the bone, +y out of the back, so x points
    away from the thumb) built by mirroring the left glove's: its samples are the mirror image."""
    sk = glove.skeleton
    left = sk.joint_set([0, 0, 0], [0, 0, 0, 1], UPM, HandShape(curl={"index": 0.6, "thumb": 0.3}, spread=0.5))
    mirror = np.diag([-1.0, 1.0, 1.0])
    frames = Rotation.from_quat(left.orientations).as_matrix()
    right_frames = mirror @ frames @ np.diag([-1.0, 1.0, 1.0])          # columns -M x, M y, M z
    right_q = Rotation.from_matrix(right_frames).as_quat()
    placed_left = sk.place("samples", sk.transforms(left.names, left.positions, left.orientations, "left", UPM))
    placed_right = sk.place("samples", sk.transforms(left.names, left.positions @ mirror, right_q, "right", UPM))
    np.testing.assert_allclose(placed_right, placed_left @ mirror, atol=1e-12)


def test_a_longer_finger_stretches_its_samples_along_it(glove):
    sk = glove.skeleton
    rest = sk.joint_set([0, 0, 0], [0, 0, 0, 1], UPM)
    longer = rest.positions.copy()
    tip = JOINTS.index("index-finger-tip")
    longer[tip] += [0.0, 0.01 * UPM, 0.0]      # the distal phalanx 1 cm longer
    a = sk.place("samples", sk.transforms(rest.names, rest.positions, rest.orientations, "left", UPM))
    b = sk.place("samples", sk.transforms(rest.names, longer, rest.orientations, "left", UPM))
    distal = sk.sample_bone == BONE_NAMES.index("index-distal")
    base = rest.positions[JOINTS.index("index-finger-phalanx-distal"), 1]
    length = rest.positions[tip, 1] - base
    np.testing.assert_allclose(b[distal, 1] - base, (a[distal, 1] - base) * (length + 0.04) / length, atol=1e-12)
    np.testing.assert_array_equal(a[~distal], b[~distal])


def test_joint_sets_that_cannot_place_the_hand_name_the_problem(glove):
    sk = glove.skeleton
    js = sk.joint_set([0, 0, 0], [0, 0, 0, 1], UPM)
    with pytest.raises(JointsError, match="missing thumb-tip"):
        sk.transforms(list(JOINTS[:4]) + ["thumb-end"] + list(JOINTS[5:]), js.positions, js.orientations, "left", UPM)
    bad = js.orientations.copy()
    bad[JOINTS.index("middle-finger-phalanx-distal")] *= 2
    with pytest.raises(JointsError, match="middle-finger-phalanx-distal"):
        sk.transforms(js.names, js.positions, bad, "left", UPM)
    nan = js.positions.copy()
    nan[JOINTS.index("wrist")] = np.nan
    with pytest.raises(JointsError, match="wrist"):
        sk.transforms(js.names, nan, js.orientations, "left", UPM)
    # another order of the same joints places the same samples
    order = np.random.default_rng(1).permutation(25)
    a = sk.place("samples", sk.transforms(js.names, js.positions, js.orientations, "left", UPM))
    b = sk.place("samples", sk.transforms([JOINTS[i] for i in order], js.positions[order], js.orientations[order],
                                           "left", UPM))
    np.testing.assert_allclose(a, b, atol=1e-15)


def test_the_glove_files_bones_section_sets_the_joints_and_is_checked():
    path = resolve_path("config/glove.yaml")
    data = read_yaml(path)
    data["bones"] = {"index": [0.5, 0.3, 0.2], "wrist": [0.0, -0.04]}
    g = glove_from_dict(data, "g.yaml")
    p = dict(zip(*(lambda js: (js.names, js.positions))(g.skeleton.joint_set([0, 0, 0], [0, 0, 0, 1], 1.0))))
    np.testing.assert_allclose(p["index-finger-phalanx-intermediate"], [0.035, 0.0475 + 0.5 * 0.075, 0], atol=1e-12)
    np.testing.assert_allclose(p["index-finger-phalanx-distal"], [0.035, 0.0475 + 0.8 * 0.075, 0], atol=1e-12)
    np.testing.assert_allclose(p["wrist"], [0.0, -0.04, 0], atol=1e-12)
    for bones, key in (({"index": [0.5, 0.3, 0.3]}, "bones.index"), ({"indx": [0.5, 0.3, 0.2]}, "bones.indx"),
                       ({"index": [0.5, 0.5]}, "bones.index")):
        data["bones"] = bones
        with pytest.raises(ConfigError) as info:
            glove_from_dict(data, "g.yaml")
        assert info.value.key == key and info.value.file == "g.yaml"


@pytest.mark.parametrize("handedness, scale", [("left", UPM), ("right", UPM), ("left", 2 * UPM)])
def test_each_bone_map_is_its_joints_rotation_stretched_along_the_bone(glove, handedness, scale):
    """Every bone's map from arbitrary joints (random poses, float32 quaternions a little off unit
    length) against scipy's rotations: the base joint's rotation, its z column times the bone's length
    over its rest length, x turned round for the other hand, x and y scaled with the screen, moved to
    the base joint; each point through its own bone's map."""
    sk = glove.skeleton
    rng = np.random.default_rng(5)
    turns = Rotation.from_euler("zyx", rng.uniform(-180, 180, (len(JOINTS), 3)), degrees=True)   # angles: ours to pick
    q = turns.as_quat() * rng.uniform(0.9995, 1.0005, (len(JOINTS), 1))
    q = q.astype(np.float32)
    positions = rng.normal(0.0, 0.2, (len(JOINTS), 3))
    m = sk.transforms(list(JOINTS), positions, q, handedness, scale)
    for k, (_, _, base, end) in enumerate(BONES):
        j, e = JOINTS.index(base), JOINTS.index(end)
        r = Rotation.from_quat(q[j].astype(float)).as_matrix()
        stretch = np.linalg.norm(positions[e] - positions[j]) / (UPM * sk.rest_lengths[k])
        expected = r * [-scale / UPM if handedness != sk.handedness else scale / UPM, scale / UPM, stretch]
        np.testing.assert_allclose(m[k, :, :3], expected, atol=1e-12)
        np.testing.assert_allclose(m[k, :, 3], positions[j], atol=0)
    local = sk.sample_local * UPM
    placed = sk.place("samples", m)
    expected = np.einsum("nij,nj->ni", m[sk.sample_bone, :, :3], local) + m[sk.sample_bone, :, 3]
    np.testing.assert_allclose(placed, expected, atol=1e-12)
