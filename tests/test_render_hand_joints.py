"""The renderer draws the articulated hand: fingers where the joints put them, the tactile cube at rest."""
import numpy as np
import pytest

from touch4d.messages import HandJoints, HandPose, TactileField
from touch4d.render.camera import OrbitCamera
from touch4d.render.frame import Style
from touch4d.render.hud import TactileCube, amplitude_colors
from touch4d.render.offscreen import OffscreenRenderer
from touch4d.render.view import SceneView, Show
from touch4d.tactile.glove import load_glove
from touch4d.hands import HandShape

SIZE = (320, 320)
FACE_ON = OrbitCamera(yaw=0.0, pitch=0.0, distance=4.0, target=np.zeros(3), ortho=True)
WHERE = np.array([0.0, -0.2, 0.0])
IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


@pytest.fixture(scope="module")
def renderer():
    r = OffscreenRenderer(SIZE, samples=0, background=(0.0, 0.0, 0.0, 1.0), backend="clip")
    yield r
    r.release()


def lit(image, point, radius=2):
    x, y = FACE_ON.to_pixels(np.array([point]), SIZE)[0]
    return image[int(y) - radius:int(y) + radius + 1, int(x) - radius:int(x) + radius + 1, :3].max() > 40


def test_a_curled_index_is_drawn_curled_and_the_cube_keeps_its_rest_layout(renderer):
    glove = load_glove()
    upm = glove.units_per_metre
    view = SceneView(glove, Style(), Show(frame=False, hand=True, tactile=False, status=False))
    index_tip = WHERE + upm * np.array([0.035, 0.1225 - 0.004, 0.0])      # the straight index's tip
    middle_tip = WHERE + upm * np.array([0.015, 0.1305 - 0.004, 0.0])
    view.set_hand(HandPose(position=WHERE, orientation=IDENTITY, valid=True, stamp=10.0))
    image = renderer.render(view, FACE_ON)
    assert lit(image, index_tip) and lit(image, middle_tip)          # the rigid hand: fingers straight
    joints = glove.skeleton.joint_set(WHERE, IDENTITY, upm, HandShape(curl={"index": 1.0})).message(10.0)
    view.set_joints(joints)
    view.set_hand(HandPose(position=WHERE, orientation=IDENTITY, valid=True, stamp=10.0))
    image = renderer.render(view, FACE_ON)
    assert not lit(image, index_tip) and lit(image, middle_tip)      # the index folded under the palm
    # fresh joints only: a pose 0.2 s newer than the last joints draws the rigid hand again
    view.set_hand(HandPose(position=WHERE, orientation=IDENTITY, valid=True, stamp=10.2))
    assert lit(renderer.render(view, FACE_ON), index_tip)

    # the tactile cube (Fig. 17) is drawn from the samples' rest places, however the fingers bend
    cube = TactileCube()
    h = np.where(glove.samples[:, 1] > 0.05, 1.0, 0.0)
    view = SceneView(glove, Style(), Show(frame=False, hand=False, tactile=True, status=False), cube)
    view.set_joints(joints)
    view.set_hand(HandPose(position=WHERE, orientation=IDENTITY, valid=True, stamp=10.0))
    view.set_field(TactileField(positions=np.zeros((len(h), 3)), l=np.ones(len(h)), s=h, h=h, alpha=3.0, beta=0.5,
                                gamma=1.0))
    camera = OrbitCamera(yaw=0.0, pitch=0.0, distance=3.0, target=np.array(cube.center), ortho=True)
    image = renderer.render(view, camera)
    where = camera.to_pixels(cube.layout(glove.samples), SIZE)
    seen = image[where[:, 1].astype(int), where[:, 0].astype(int), :3].astype(int)
    assert np.abs(seen - np.round(amplitude_colors(h) * 255)).max() <= 2


def test_joints_that_cannot_place_the_hand_are_refused_and_the_pose_is_drawn(renderer):
    glove = load_glove()
    view = SceneView(glove, Style(), Show(frame=False, hand=True, tactile=False, status=False))
    bad = HandJoints(handedness="left", names=["wrist"], positions=np.zeros((1, 3)), orientations=np.array([IDENTITY]),
                     radii=np.ones(1), valid=True, stamp=5.0)
    with pytest.raises(ValueError, match="names"):
        view.set_joints(bad)
    view.set_hand(HandPose(position=WHERE, orientation=IDENTITY, valid=True, stamp=5.0))
    assert lit(renderer.render(view, FACE_ON), WHERE + glove.units_per_metre * np.array([0.035, 0.118, 0.0]))
