"""The page's own touch (the node's `touch: page`, launch/quest.yaml) in a real browser (Debian's
chromium, a Quest 3 emulated by iwer): on random scenes and controller poses the intensities the
page computes (the renderer's ray test per glove sample, eq. 1-3 and the motors' mix, in
touch4d/web/static/touch.js) equal, within 0.01 of full drive, the tactile node's for the same pose
(its tactile/field, mixed by the glove's motors) and the Python model's; for the held controller
(config/gloves/quest-controller.yaml, what it pulses) and per motor for the 30-motor glove
(config/glove.yaml, what would go to its motors); in the projection and in a slice view that touches
its cross-section. What the page played comes back on tactile/motors."""
from __future__ import annotations

import time

import numpy as np
import pytest

from gpu_tactile_cases import random_pose, random_scene
from test_web_haptics_browser import RECORD_PULSES, pulses
from touch4d.bus import Node
from touch4d.bus.testing import collect, free_port, launch_process, wait_until
from touch4d.configfile import CONFIG_DIR
from touch4d.messages import MotorCommand, SceneState, TactileField
from touch4d.tactile import compute_stimulus, load_glove
from touch4d.tactile.pose import place
from touch4d.tracking.calibration import load_calibration
from touch4d.web.testing import chromium, enter_vr, headset_page

pytestmark = pytest.mark.timeout(400)

GLOVES = {"controller": "config/gloves/quest-controller.yaml", "glove": "config/glove.yaml"}
TOLERANCE = 0.01              # of full drive
SCENES, POSES = 6, 7          # random scenes (four projections, two slice views), poses in each


@pytest.fixture(scope="module")
def browser():
    with chromium() as b:
        yield b


def stack(glove: str):
    """launch/quest.yaml with the test as the scene (no scene node), the tactile node on `glove` too."""
    port = free_port()
    args = ["launch/quest.yaml", "monitor:=none", "scene:=none", f"tracker.port:={port}",
            "tracker.save_calibration:=false", f"tracker.glove:={glove}", f"tactile.glove:={glove}"]
    return port, launch_process(args)


def show_scene(page, watcher, publisher, msg: SceneState) -> None:
    """Publish the scene until the page has adopted it (its frame carries the revision)."""
    def adopted():
        publisher.publish(msg)
        return page.evaluate(f"Boolean(touch4d.frame && touch4d.frame.revision === {msg.revision} && "
                             f"touch4d.geometry)")
    wait_until(adopted, timeout=20, interval=0.1, spin=watcher)


def hold(page, watcher, cal, position, orientation) -> dict:
    """Put the controller where the glove hand is at `position`, `orientation` (screen) and wait for
    the page's touch of a pose read after that: {grip, V, played, ...}."""
    room, quat = cal.controller_from_hand(position, orientation)
    t0 = page.evaluate("performance.timeOrigin + performance.now()")
    page.evaluate("([p, q]) => { xr.controllers.right.position.set(...p); xr.controllers.right.quaternion.set(...q); }",
                  [room.tolist(), quat.tolist()])
    try:
        return wait_until(lambda: page.evaluate(f"touch4d.touch && touch4d.touch.time > {t0} + 20 ? touch4d.touch : null"),
                          timeout=20, spin=watcher)
    except TimeoutError:
        state = page.evaluate("JSON.stringify({time: touch4d.touch && touch4d.touch.time, passes: touch4d.touch && "
                              "touch4d.touch.passes, xr: touch4d.xrFrames, error: touch4d.error, session: "
                              "Boolean(touch4d.session), sources: touch4d.input && touch4d.input.sources})")
        raise AssertionError(f"no touch from the page for a pose set at {t0}: {state}") from None


@pytest.mark.parametrize("glove_name", sorted(GLOVES))
def test_the_pages_touch_equals_the_tactile_nodes_on_random_scenes_and_poses(browser, glove_name):
    glove = load_glove(GLOVES[glove_name])
    cal = load_calibration(None, "hand_in_grip")
    port, launching = stack(GLOVES[glove_name])
    with launching as run:
        bus = run.wait_ready(60)
        run.wait_for_line("WebXR page", timeout=60)
        watcher = Node("touch-test", bus=bus, heartbeat=False)
        fields = collect(watcher, "tactile/field", TactileField)
        motors = collect(watcher, "tactile/motors", MotorCommand)
        scenes = watcher.create_publisher("scene/state", SceneState)
        page = headset_page(browser, f"http://127.0.0.1:{port}/", 320, 180)
        try:
            enter_vr(page)
            page.evaluate("xr.position.set(0, 1.5, 0.8); xr.quaternion.set(0, 1, 0, 0)")   # cheap frames
            page.evaluate(RECORD_PULSES)
            rng = np.random.default_rng(31)
            worst_node, worst_model, touching, published, sections = 0.0, 0.0, 0, 0, 0
            for k in range(SCENES):
                # the last two: the slice view touching its cross-section (ray_caster: a SectionCaster)
                cut = float(rng.uniform(1.0, 2.4)) if k >= SCENES - 2 else None
                scene = random_scene(rng, ("orthographic", "perspective")[k % 2], slice_w=cut)
                msg = scene.to_message()
                msg.revision = 100 + k
                show_scene(page, watcher, scenes, msg)
                caster = scene.ray_caster()
                for _ in range(POSES):
                    position, orientation = random_pose(rng, 0.6)
                    since = len(motors)      # what the page plays for this pose goes out after this
                    got = hold(page, watcher, cal, position, orientation)
                    grip = np.asarray(got["grip"])
                    hand_at, hand_q = cal.hand_from_controller(grip[:3], grip[3:])
                    expected = place(glove.samples, glove.units_per_metre, hand_at, hand_q)
                    page_v = np.asarray(got["V"])

                    def node_value():
                        """The tactile node's latest field for the same pose (the page's grip, sent to it)."""
                        field = next((f for f in reversed(fields) if f.positions.shape == expected.shape
                                      and np.abs(f.positions - expected).max() < 1e-5), None)
                        return None if field is None else glove.gamma * glove.weight_matrix @ field.h

                    # the node may still cast through the scene before (a loaded machine builds the new one
                    # later than the page adopts it): its fields for this pose come until it agrees, or not
                    try:
                        wait_until(lambda: (v := node_value()) is not None and np.abs(page_v - v).max() <= TOLERANCE,
                                   timeout=20, spin=watcher)
                    except TimeoutError:
                        pass                 # the assertion below says by how much they differ
                    node_v = node_value()
                    assert node_v is not None, "the tactile node sent no field for the page's pose"
                    model_v = compute_stimulus(glove, caster, hand_at, hand_q).V
                    worst_node = max(worst_node, float(np.abs(page_v - node_v).max()))
                    worst_model = max(worst_model, float(np.abs(page_v - model_v).max()))
                    touching += bool(model_v.max() > 0.05)
                    sections += bool(cut is not None and model_v.max() > 0.05)
                    # what it played goes out on tactile/motors, the page's values
                    # (on a loaded machine the page's fail safe may play 0 for a while instead: counted, not waited on)
                    try:
                        wait_until(lambda: any(len(m.intensity) == len(page_v) and np.abs(m.intensity - page_v).max()
                                               < 1e-9 for m in motors[since:]), timeout=5, spin=watcher)
                        published += 1
                    except TimeoutError:
                        pass
            poses = SCENES * POSES
            print(f"{glove_name}: page vs node {worst_node:.2e}, vs model {worst_model:.2e}, {touching}/{poses} "
                  f"poses touch, {sections} of them a slice's section")
            assert worst_node <= TOLERANCE, f"the page differs from the tactile node by {worst_node:.4f}"
            assert worst_model <= TOLERANCE, f"the page differs from the Python model by {worst_model:.4f}"
            assert touching >= poses // 4, f"only {touching} of {poses} poses touch anything: the cases prove little"
            assert sections >= 2, f"only {sections} poses touch a slice's section: the cases prove little"
            assert published >= poses // 2, f"what the page played reached tactile/motors for only {published} of {poses} poses"
            if glove_name == "controller":   # the controller plays its one motor, the strongest
                played = [v for h, v, _, _ in pulses(page) if h == "right"]
                assert played and max(played) > 0.05 and all(0 <= v <= 1 for v in played)
        finally:
            page.context.close()
            watcher.shutdown()


def test_the_pages_touch_fails_safe(browser):
    """No scene yet: nothing played; a scene: full drive on the hypercube's front cell, played and
    published; a visual trial: 0 played and published; the controller's tracking lost: 0 played within
    100 ms and published; the page hidden: the node publishes 0 on tactile/motors within 100 ms; the
    session ended: 0 played within 100 ms."""
    from test_web_haptics_browser import CENTER, trial
    from touch4d.geometry.scene import load_scene
    from touch4d.messages import StudyTrial

    port, launching = stack(GLOVES["controller"])
    with launching as run:
        bus = run.wait_ready(60)
        run.wait_for_line("WebXR page", timeout=60)
        watcher = Node("touch-safe-test", bus=bus, heartbeat=False)
        motors = collect(watcher, "tactile/motors", MotorCommand)
        scenes = watcher.create_publisher("scene/state", SceneState)
        trials = watcher.create_publisher("study/trial", StudyTrial)
        page = headset_page(browser, f"http://127.0.0.1:{port}/", 320, 180)
        try:
            enter_vr(page)
            page.evaluate("xr.position.set(0, 1.5, 0.8); xr.quaternion.set(0, 1, 0, 0)")
            page.evaluate(RECORD_PULSES)
            page.evaluate("xr.controllers.right.position.set({}, {}, {})".format(*CENTER))
            watcher.spin(1.5)
            assert page.evaluate("touch4d.touch") is None          # no scene, no pass
            assert all(v == 0 for _, v, _, _ in pulses(page))
            assert all(m.intensity.max() == 0 for m in motors)
            msg = load_scene("config/scenes/hypercube.yaml").to_message()
            msg.revision = 7
            show_scene(page, watcher, scenes, msg)
            wait_until(lambda: [v for _, v, _, _ in pulses(page) if v > 0.99], timeout=20, spin=watcher)
            wait_until(lambda: [m for m in motors if m.intensity.max() > 0.99], timeout=20, spin=watcher)
            assert page.evaluate("touch4d.touch.played")[0] > 0.99    # the page's own touch played it
            t = page.evaluate("performance.timeOrigin + performance.now()") / 1000
            trials.publish(trial("visual"))
            wait_until(lambda: [v for _, v, _, pt in pulses(page) if pt >= t and v == 0], timeout=10, spin=watcher)
            watcher.spin(0.5)
            t1 = page.evaluate("performance.timeOrigin + performance.now()") / 1000
            watcher.spin(0.5)
            assert all(v == 0 for _, v, _, pt in pulses(page) if pt >= t1)
            assert all(m.intensity.max() == 0 for m in motors if m.stamp >= t1)
            trials.publish(trial("touch"))
            wait_until(lambda: [m for m in motors if m.stamp > t1 and m.intensity.max() > 0.99], timeout=20,
                       spin=watcher)
            # the controller's tracking lost: 0 played within 100 ms, and 0 published
            t2 = page.evaluate("() => { const t = performance.timeOrigin + performance.now(); "
                               "xr.controllers.right.connected = false; return t / 1000; }")
            zero = wait_until(lambda: next((pt for _, v, _, pt in pulses(page) if pt >= t2 and v == 0), None),
                              timeout=5, spin=watcher)
            assert zero - t2 < 0.1, f"0 played {1000 * (zero - t2):.0f} ms after tracking was lost"
            wait_until(lambda: [m for m in motors if m.stamp >= t2 and m.intensity.max() == 0], timeout=5,
                       spin=watcher)
            page.evaluate("xr.controllers.right.connected = true")
            page.evaluate(RECORD_PULSES)      # the controller's actuator anew
            t3 = page.evaluate("performance.timeOrigin + performance.now()") / 1000
            wait_until(lambda: [m for m in motors if m.stamp > t3 and m.intensity.max() > 0.99], timeout=20,
                       spin=watcher)
            t0 = page.evaluate("() => { const t = performance.timeOrigin + performance.now(); "
                               "xr.updateVisibilityState('hidden'); return t / 1000; }")
            zero = wait_until(lambda: next((m for m in motors if m.stamp >= t0 and m.intensity.max() == 0), None),
                              timeout=5, spin=watcher)
            assert zero.stamp - t0 < 0.1, f"0 published {1000 * (zero.stamp - t0):.0f} ms after the page hid"
            # visible again, then the session ends: 0 played within 100 ms
            page.evaluate("xr.updateVisibilityState('visible')")
            t4 = page.evaluate("performance.timeOrigin + performance.now()") / 1000
            wait_until(lambda: [v for _, v, _, pt in pulses(page) if pt > t4 and v > 0.99], timeout=20, spin=watcher)
            t5 = page.evaluate("() => { const t = performance.timeOrigin + performance.now(); "
                               "touch4d.session.end(); return t / 1000; }")
            zero = wait_until(lambda: next((pt for _, v, _, pt in pulses(page) if pt >= t5 and v == 0), None),
                              timeout=5, spin=watcher)
            assert zero - t5 < 0.1, f"0 played {1000 * (zero - t5):.0f} ms after the session ended"
        finally:
            page.context.close()
            watcher.shutdown()
