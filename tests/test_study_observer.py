"""Model observers and the offline simulation: look-alikes are told apart by touch and not by sight;
a whole study runs headless into the agreed trials.csv and is analysed."""
import csv
import json
import math

import numpy as np
import pytest
from scipy.stats import binomtest

from touch4d.cli import main
from touch4d.errors import ConfigError
from touch4d.study.design import load_study
from touch4d.study.infotransfer import predicted_transfer
from touch4d.study.observer import ModelObserver, every_sample_glove, patterns_at
from touch4d.study.plan import plan_session
from touch4d.study.glovedesign import glove_file_of
from touch4d.study.psychophysics import (FINGERTIP_WEBER_DB, HUMAN_NOISE, PALM_LOCALISATION_MM, REFERENCE_DRIVE,
                                         THENAR_WEBER, noise_for_weber, weber_from_db)
from touch4d.study.simulate import Timing, simulate_trial
from touch4d.study.stimuli import trial_scene
from touch4d.study.table import COLUMNS
from touch4d.tactile import compute_stimulus, load_glove
from touch4d.tactile.glove import glove_from_dict


@pytest.fixture(scope="module")
def paper():
    return load_study("config/studies/paper.yaml")


@pytest.fixture(scope="module")
def glove():
    return load_glove()


def test_look_alikes_are_at_chance_by_sight_and_well_above_it_by_touch(paper, glove):
    observer = ModelObserver(glove, paper, seed=2, lapse=0.0, train_scenes=6, train_positions=10, view_scenes=15)
    correct = {"visual": [], "touch": []}
    for participant in ("P01", "P02", "P03", "P04"):
        for trial in plan_session(paper, participant):
            if trial.task == "lookalikes" and trial.condition in correct and not trial.practice:
                if len(correct[trial.condition]) < 48:
                    result = simulate_trial(observer, glove, paper, trial, seed=0, timing=Timing())
                    correct[trial.condition].append(result["response"] == trial.answer)
    visual, touch = (np.array(correct[c]) for c in ("visual", "touch"))
    assert len(visual) == len(touch) == 48
    # The three project to the same ball: sight cannot beat chance (1/3) ...
    assert binomtest(int(visual.sum()), len(visual), 1 / 3).pvalue > 0.01
    # ... while the cone's peak, the flat front's uniform field and the hollow's ring are felt.
    assert touch.mean() > 0.85


def test_the_visual_condition_withholds_the_patterns_and_the_touch_condition_the_view(paper, glove):
    calls = []

    class Spy(ModelObserver):
        def respond(self, trial, patterns, scene, rng):
            calls.append((trial.condition, patterns is None, scene is None))
            return trial.options[0]

    spy = Spy(glove, paper)
    for trial in [t for t in plan_session(paper, "P01") if not t.practice][::40]:
        simulate_trial(spy, glove, paper, trial, seed=0, timing=Timing())
    seen = set(calls)
    assert ("visual", True, False) in seen and ("touch", False, True) in seen and ("visual+touch", False, False) in seen
    assert all((c == "visual") == no_patterns and (c == "touch") == no_scene for c, no_patterns, no_scene in seen)


def test_patterns_are_the_tactile_models_intensities(paper, glove):
    trial = next(t for t in plan_session(paper, "P01") if t.task == "front")
    scene = trial_scene(paper, trial)
    positions = np.array([[0.0, 0.0, 0.0], [0.1, -0.2, 0.3]])
    got = patterns_at(glove, scene, positions)
    for p, pattern in zip(positions, got):
        np.testing.assert_array_equal(pattern, compute_stimulus(glove, scene.ray_caster(), p, [0, 0, 0, 1.0]).V)


def test_the_every_sample_glove_has_a_motor_at_each_sample_driven_by_its_h(paper, glove):
    dense = every_sample_glove(glove)
    assert len(dense.motor_names) == len(glove.samples) == 247
    trial = next(t for t in plan_session(paper, "P01") if t.task == "lookalikes")
    st = compute_stimulus(dense, trial_scene(paper, trial).ray_caster(), [0.05, -0.1, 0.0], [0, 0, 0, 1.0])
    np.testing.assert_allclose(st.V, glove.gamma * st.h)        # eq. 3 at every sample


def test_predicted_information_transfer_is_bounded_and_high_for_look_alikes(paper, glove):
    out = predicted_transfer(glove, paper, "lookalikes", scenes=6, positions=8)
    assert 1.0 < out["bits"] <= out["max_bits"] == pytest.approx(math.log2(3))
    assert np.sum(out["confusion"]) == out["test_patterns"]


def test_an_offline_study_writes_the_agreed_table_reproducibly_and_is_analysed(tmp_path, capsys):
    args = ["study", "run", "config/studies/paper.yaml", "--simulate", "--offline", "--participants", "2", "--quick",
            "--seed", "4"]
    assert main(args + ["--out", str(tmp_path / "a")]) == 0
    assert main(args + ["--out", str(tmp_path / "b")]) == 0
    capsys.readouterr()
    for participant in ("P01", "P02"):
        table = (tmp_path / "a" / participant / "trials.csv").read_text()
        assert table == (tmp_path / "b" / participant / "trials.csv").read_text()   # same seed, same answers
        rows = list(csv.DictReader(table.splitlines()))
        assert tuple(rows[0]) == COLUMNS and len(rows) == 42
        assert {r["participant"] for r in rows} == {participant}
        for r in rows:
            assert r["correct"] == str(int(r["response"] == r["answer"]))
            assert (float(r["time_touching_s"]) == 0) == (r["condition"] == "visual")
        manifest = json.loads((tmp_path / "a" / participant / "manifest.json").read_text())
        assert manifest["mode"] == "offline simulation" and manifest["participant"] == participant
        assert manifest["condition_order"] == [r["condition"] for r in rows][::14]
    assert main(["study", "analyze", str(tmp_path / "a"), "--json", "--no-report", "--bootstrap", "0"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["participants"] == ["P01", "P02"] and out["tasks"]["tilt"]["touch"]["n"] == 16


def test_check_and_plan_commands(capsys, tmp_path):
    assert main(["study", "check", "config/studies/paper.yaml"]) == 0
    assert "213 trials (9 practice)" in capsys.readouterr().out
    assert main(["study", "plan", "config/studies/paper.yaml", "--participant", "P02", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["row"] == 1 and len(out["trials"]) == 213 and out["trials"][0]["practice"] is True
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\ntasks:\n  - {id: t, kind: tilt, prompt: '?', options: [l, r], scene: config/scenes/hypercube.yaml,"
                   " angles_deg: [2], plane: xq}\n")
    assert main(["study", "check", str(bad)]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "tasks[0].plane" in err and "'xq'" in err


def test_a_turn_through_w_would_show_the_look_alikes_apart_so_the_study_leaves_them_unturned(paper):
    from touch4d.study.observer import view_features
    from touch4d.study.stimuli import stimulus_scene

    def outline(name, turn):
        return view_features(stimulus_scene(paper, "lookalikes", name, math.nan, turn), grid=21)

    names = ("convex", "flat", "concave")
    for turn in ([], [("xy", 3.0), ("yz", -3.0)]):              # as shown, or turned within the screen: one ball
        views = [outline(n, turn) for n in names]
        assert all(np.array_equal(views[0], v) for v in views[1:])
    # 3 degrees in xw: the prisms' depth (1.6 units) widens their outline by 1.6 sin 3 deg; the cone's
    # apex stays inside its base.
    turned = {n: outline(n, [("xw", 3.0)]).sum() for n in names}
    assert turned["flat"] > turned["convex"] and turned["concave"] > turned["convex"]
    assert all(t.jitter_deg == 0 for t in paper.tasks if t.kind == "look-alikes")


def test_transfer_reports_bits_per_task_for_the_glove_and_the_every_sample_glove(capsys):
    assert main(["study", "transfer", "config/studies/paper.yaml", "--task", "lookalikes", "--every-sample",
                 "--scenes", "4", "--positions", "6", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert [(r["task"], r["motors"]) for r in out["results"]] == [("lookalikes", 30), ("lookalikes", 247)]
    for r in out["results"]:
        assert 0 < r["bits"] <= r["max_bits"] + 1e-9 and np.sum(r["confusion"]) == r["test_patterns"] == 3 * 2 * 6


def test_the_transfer_table_rounds_the_bits_and_their_maximum_alike():
    from touch4d.commands.study import transfer_table

    perfect = {"task": "lookalikes", "motors": 30, "bits": math.log2(3), "max_bits": math.log2(3), "accuracy": 1.0}
    row = transfer_table([perfect]).splitlines()[1].split()
    assert row[2] == row[3] == "1.585"


def test_few_training_scenes_train_or_are_refused_naming_the_setting(paper, glove):
    # two views per stimulus: too few to hold one out for the temperature, enough to learn from
    observer = ModelObserver(glove, paper, seed=1, train_scenes=4, train_positions=8, view_scenes=2).train()
    assert all(np.isfinite(observer.view_cue(task.id).temperature) for task in paper.tasks)
    with pytest.raises(ConfigError, match="view_scenes"):     # one view per stimulus: no more than the answers
        ModelObserver(glove, paper, seed=1, train_scenes=4, train_positions=8, view_scenes=1).train()


def test_the_default_observer_localises_a_vibration_on_the_palm_as_people_do(paper, glove):
    observer = ModelObserver(glove, paper)
    measured = observer.localisation(trials=3000, seed=1)
    low, high = PALM_LOCALISATION_MM
    assert low <= measured["mean_error_mm"] <= high, measured
    assert ModelObserver(glove, paper, localisation_mm=2.0).localisation(trials=3000, seed=1)["mean_error_mm"] < low
    with pytest.raises(ConfigError, match="localisation_mm"):
        ModelObserver(glove, paper, localisation_mm=-1.0)


# Each skin's published amplitude discrimination: its Weber fraction and the noise that gives it (closed form).
FINGERTIP = weber_from_db(sum(FINGERTIP_WEBER_DB) / 2.0)
SKIN = {"palm": (THENAR_WEBER, noise_for_weber(THENAR_WEBER)), "finger": (FINGERTIP, noise_for_weber(FINGERTIP))}


def felt_noise(observer, motors: int, seed: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """The sd per motor of what the observer feels of a steady drive at the reference, and what it felt."""
    rng = np.random.default_rng(seed)
    drive = np.full((20000, motors), REFERENCE_DRIVE)
    felt = observer.feel(drive, rng)
    return np.std(felt - drive, axis=0), felt


@pytest.mark.parametrize("region, skin", [("palm", "palm"), ("index", "finger"), ("thumb", "finger"),
                                          ("back", "finger")])
def test_a_motor_is_felt_with_the_noise_of_the_skin_it_sits_on(paper, glove, region, skin):
    # a glove whose motors all sit in one region of the hand; the participant's one noise: the fingertip's
    places = glove.hand.regions(glove.samples)[region]
    observer = ModelObserver(glove_from_dict(glove_file_of(glove.path, glove, places)), paper, noise=HUMAN_NOISE)
    weber, sd = SKIN[skin]
    spread, reference = felt_noise(observer, len(places))
    assert spread == pytest.approx(np.full(len(places), sd), rel=0.03)
    # two-interval amplitude discrimination at the skin's published 75% step
    comparison = observer.feel(np.full(reference.shape, REFERENCE_DRIVE * (1.0 + weber)), np.random.default_rng(8))
    assert np.mean(comparison > reference) == pytest.approx(0.75, abs=0.01)
    # one free parameter a participant: a noisier one is noisier on every skin alike
    assert felt_noise(observer.with_noise(2.0), len(places))[0] == pytest.approx(np.full(len(places), 2 * sd), rel=0.03)


def test_the_every_sample_glove_feels_its_palm_samples_with_the_thenars_noise(paper, glove):
    observer = ModelObserver(every_sample_glove(glove), paper)
    spread, _ = felt_noise(observer, len(glove.samples))
    regions = glove.hand.regions(glove.samples)
    assert spread[regions["palm"]] == pytest.approx(np.full(len(regions["palm"]), SKIN["palm"][1]), rel=0.04)
    for region in ("back", "index", "little"):
        assert spread[regions[region]] == pytest.approx(np.full(len(regions[region]), SKIN["finger"][1]), rel=0.04)


def test_a_held_controller_vibrates_the_hand_around_its_grip_so_it_is_felt_with_the_fingertips_noise(paper):
    controller = load_glove("config/gloves/quest-controller.yaml")
    assert controller.hand.regions(controller.motor_positions)["palm"] == [0]    # its grip lies under the palm
    spread, _ = felt_noise(ModelObserver(controller, paper), 1)
    assert spread == pytest.approx([SKIN["finger"][1]], rel=0.03)
