"""The scene files of config/scenes/: they load, sit behind the screen inside its cube, the
look-alikes look alike, and the multi-object scene really hides part of one object behind another."""
import numpy as np
import pytest
from scipy.spatial import ConvexHull

from touch4d.geometry.raycast import RayCaster
from touch4d.geometry.scene import load_scene
from touch4d.geometry.shapes import list_shapes
from touch4d.tracking.config import CONFIG_DIR

SCENES = sorted((CONFIG_DIR / "scenes").glob("*.yaml"))
REGULAR = ("5-cell", "tesseract", "16-cell", "24-cell", "120-cell", "600-cell")


def vertices(obj):
    return np.vstack([p.vertices for p in obj.world_parts()])


def test_the_promised_scenes_exist():
    names = {p.stem for p in SCENES}
    assert {"hypercube", "convex-front", "flat-front", "concave-front", "multi-object", *REGULAR} <= names
    shapes = {load_scene(CONFIG_DIR / "scenes" / f"{name}.yaml").objects[0].shape for name in REGULAR}
    assert shapes == set(REGULAR) and set(REGULAR) <= set(list_shapes())


@pytest.mark.parametrize("path", SCENES, ids=lambda p: p.stem)
def test_scene_loads_sits_behind_the_screen_and_projects_inside_it(path):
    scene = load_scene(path)
    scene.to_message().validate()
    for obj in scene.objects:
        v = vertices(obj)
        assert v[:, 3].min() > 0, f"{obj.name} crosses the screen hyperplane w = 0"
        assert np.abs(v[:, :3]).max() <= 1.0, f"{obj.name} projects outside the screen cube"


def test_look_alikes_share_their_silhouette_and_differ_in_depth():
    fronts, seen = {}, {}
    points = np.random.default_rng(4).uniform(-0.9, 0.9, (4000, 3))
    for name in ("convex-front", "flat-front", "concave-front"):
        scene = load_scene(CONFIG_DIR / "scenes" / f"{name}.yaml")
        caster = scene.ray_caster()
        fronts[name] = caster.cast(np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0]]))[0]
        seen[name] = caster.cast(points)[1] >= 0
    # Fig. 20(a): seen from the front all three are the same ball, point for point in the whole screen
    # (away from its boundary, where rounding decides), not just in their extent.
    flat = load_scene(CONFIG_DIR / "scenes" / "flat-front.yaml").objects[0]
    ball = ConvexHull(vertices(flat)[:, :3])
    margin = (points @ ball.equations[:, :3].T + ball.equations[:, 3]).max(axis=1)
    clear = np.abs(margin) > 1e-9
    assert 1000 < (margin < 0).sum() < 3000
    for name, hit in seen.items():
        assert np.array_equal(hit[clear], (margin < 0)[clear]), name
    # from the front they look the same; along w the cone recedes from its apex at the centre, the
    # flat front stays level and the hollow is deepest at the centre
    convex, flat, concave = fronts["convex-front"], fronts["flat-front"], fronts["concave-front"]
    assert flat[0] == pytest.approx(flat[1])
    assert convex[0] == pytest.approx(flat[0]) and convex[1] > flat[1]
    assert concave[0] > flat[0] and concave[1] < concave[0]


def test_multi_object_scene_hides_part_of_the_back_object():
    scene = load_scene(CONFIG_DIR / "scenes" / "multi-object.yaml")
    grid = np.stack(np.meshgrid(*[np.linspace(-1, 1, 21)] * 3, indexing="ij"), -1).reshape(-1, 3)
    _, hit = scene.ray_caster().cast(grid)
    parts = scene.world_parts()
    back = RayCaster([(i, p) for i, p in parts if i == 1]).cast(grid)[1] == 1
    front = RayCaster([(i, p) for i, p in parts if i == 0]).cast(grid)[1] == 0
    assert (back & front).sum() > 20 and np.all(hit[back & front] == 0)   # hidden where covered
    assert (back & ~front).sum() > 20 and np.all(hit[back & ~front] == 1)  # seen beside it
    assert (hit == 2).sum() > 0
