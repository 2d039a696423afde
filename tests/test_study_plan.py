"""Study files and plans: counterbalanced condition orders, reproducible trials, the run constraint,
trial scenes, and errors that name file, key, expected and got."""
import collections
import hashlib
import itertools
import math

import msgspec
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from touch4d.errors import ConfigError
from touch4d.study.design import load_study, parse_study, replace_study
from touch4d.study.plan import (balanced_latin_square, condition_order, constrained_shuffle, participant_index,
                                plan_session, quick_plan)
from touch4d.study.stimuli import scene_mapping, trial_scene
from touch4d.tactile import compute_stimulus, load_glove


@pytest.fixture(scope="module")
def paper():
    return load_study("config/studies/paper.yaml")


def with_fields(study, **fields):
    return replace_study(study, **fields)


# ---- counterbalancing ---------------------------------------------------------------------------------


def test_six_participants_meet_every_order_of_three_conditions_once(paper):
    orders = [tuple(condition_order(paper, f"P{k:02d}")) for k in range(1, 7)]
    assert sorted(orders) == sorted(itertools.permutations(["visual", "touch", "visual+touch"]))
    # the seventh starts the table again
    assert condition_order(paper, "P07") == condition_order(paper, "P01")


@pytest.mark.parametrize("n", [2, 3, 4, 5, 6])
def test_balanced_latin_square_balances_positions_and_neighbours(n):
    rows = balanced_latin_square(n)
    assert len(rows) == (n if n % 2 == 0 else 2 * n)
    for row in rows:
        assert sorted(row) == list(range(n))
    for column in zip(*rows):                          # each item equally often in each position
        assert len(set(collections.Counter(column).values())) == 1
    pairs = collections.Counter((a, b) for row in rows for a, b in zip(row, row[1:]))
    assert set(pairs) == {(a, b) for a in range(n) for b in range(n) if a != b}
    assert len(set(pairs.values())) == 1               # each ordered pair of neighbours equally often


def test_a_latin_study_uses_the_balanced_square(paper):
    latin = with_fields(paper, counterbalance="latin")
    orders = [tuple(condition_order(latin, f"P{k:02d}")) for k in range(1, 7)]
    assert len(set(orders)) == 6                       # odd n: the square and its mirror, 2n rows


def test_participant_ids_map_to_rows_by_number_or_by_documented_hash(paper):
    assert [participant_index(paper, f"P{k:02d}") for k in range(1, 8)] == [0, 1, 2, 3, 4, 5, 0]
    assert participant_index(paper, "p3") == 2
    digest = int.from_bytes(hashlib.sha256(b"alice").digest()[:8], "big")
    assert participant_index(paper, "alice") == digest % 6


# ---- reproducible plans -----------------------------------------------------------------------------------


def test_the_same_study_and_participant_give_the_same_session(paper):
    again = load_study("config/studies/paper.yaml")
    first, second = plan_session(paper, "P03"), plan_session(again, "P03")
    assert first == second and condition_order(paper, "P03") == condition_order(again, "P03")
    other = plan_session(paper, "P04")
    assert [t.stimulus for t in other] != [t.stimulus for t in first]


def test_a_session_holds_every_stimulus_repetitions_times_per_condition(paper):
    trials = plan_session(paper, "P02")
    main = [t for t in trials if not t.practice]
    counts = collections.Counter((t.condition, t.task, t.stimulus) for t in main)
    for task in paper.tasks:
        for condition in paper.conditions:
            for name in task.stimulus_names():
                assert counts[(condition, task.id, name)] == paper.repetitions_of(task)
    blocks = [[t for t in trials if t.block == b] for b in range(3)]
    assert [b[0].condition for b in blocks] == condition_order(paper, "P02")
    for block in blocks:
        assert [t.practice for t in block] == [True] * paper.practice + [False] * (len(block) - paper.practice)
        assert [t.trial for t in block] == list(range(len(block)))
        assert [t.index for t in block[1:]] == [t.index + 1 for t in block[:-1]]
        breaks = [t.trial for t in block if t.break_before]
        # every break_every trials, none with fewer than half a stretch left before the block's end
        assert breaks == [p for p in range(paper.break_every, len(block), paper.break_every)
                          if len(block) - p >= paper.break_every / 2]


def test_tilt_trials_answer_by_the_sign_of_their_level(paper):
    for t in plan_session(paper, "P01"):
        if t.kind == "tilt":
            assert t.answer == ("right" if t.level > 0 else "left") and t.stimulus == f"tilt{t.level:+g}"
            assert all(plane != "xw" for plane, _ in t.transform)
        else:
            assert math.isnan(t.level)
        assert all(abs(d) <= paper.task(t.task).jitter_deg for _, d in t.transform)


def test_a_quick_plan_shows_each_stimulus_once_per_condition(paper):
    trials = quick_plan(paper, "P05")
    counts = collections.Counter((t.condition, t.stimulus) for t in trials)
    assert set(counts.values()) == {1} and len(trials) == 3 * (3 + 3 + 8)
    assert not any(t.practice for t in trials) and [t.index for t in trials] == list(range(len(trials)))


def longest_runs(trials):
    """The longest run of equal correct answers in each block (practice included)."""
    out = []
    for _, block in itertools.groupby(trials, key=lambda t: t.block):
        answers = [t.answer for t in block]
        out.append(max(len(list(g)) for _, g in itertools.groupby(answers)))
    return out


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), max_run=st.integers(1, 4), participant=st.sampled_from(["P01", "P04", "zoe"]))
def test_no_block_has_more_than_max_run_equal_answers_in_a_row(paper, seed, max_run, participant):
    study = with_fields(paper, seed=seed, max_run=max_run)
    trials = plan_session(study, participant)
    assert max(longest_runs(trials)) <= max_run
    counts = collections.Counter((t.condition, t.stimulus) for t in trials if not t.practice)
    assert set(counts.values()) == {4, 6}             # the constraint never drops or repeats a trial


def test_the_run_constraint_is_not_vacuous(paper):
    # Without it, shuffles of these blocks often hold runs of 4 or more (tilt answers are 47% of them).
    rng = np.random.default_rng(0)
    answers = [t.answer for t in plan_session(paper, "P01") if t.block == 0]
    runs = [max(len(list(g)) for _, g in itertools.groupby(rng.permutation(answers))) for _ in range(50)]
    assert max(runs) > paper.max_run


def test_an_impossible_run_limit_names_max_run():
    with pytest.raises(ConfigError) as info:
        constrained_shuffle(list("aaaaab"), 1, np.random.default_rng(0), key=lambda x: x, file="s.yaml")
    assert info.value.key == "max_run" and info.value.got == 1 and "max_run >= 3" in info.value.expected


# ---- trial scenes ------------------------------------------------------------------------------------------


def test_a_tilt_trial_turns_the_front_cell_by_its_level(paper):
    trial = next(t for t in plan_session(paper, "P01") if t.kind == "tilt")
    bare = msgspec.structs.replace(trial, transform=[])
    scene = trial_scene(paper, bare)
    poly = scene.objects[0].world_parts()[0]
    front = poly.normals[np.argmin(poly.normals[:, 3])]          # the facet facing the viewer (-w)
    theta = np.radians(trial.level)
    np.testing.assert_allclose(front, [np.sin(theta), 0, 0, -np.cos(theta)], atol=1e-12)
    assert scene_mapping(paper, trial)["objects"][0]["rotation"][0] == ["xw", trial.level]


def test_a_left_tilt_is_felt_stronger_on_the_right_as_in_the_paper(paper):
    # Fig. 18a: "If the cell is tilted slightly to the left, the stimulus becomes greater on the right."
    glove = load_glove()
    right = np.array([name.startswith(("thumb", "index")) or name.endswith("index") for name in glove.motor_names])
    left = np.array([name.startswith(("little", "ring")) or name.endswith("little") for name in glove.motor_names])
    for answer in ("left", "right"):
        trial = next(t for t in plan_session(paper, "P01") if t.kind == "tilt" and t.answer == answer
                     and abs(t.level) == 16)
        st_ = compute_stimulus(glove, trial_scene(paper, trial).ray_caster(), [-0.14, -0.18, 0.0], [0, 0, 0, 1.0])
        stronger_right = st_.V[right].mean() > st_.V[left].mean()
        assert stronger_right == (answer == "left")


# ---- study files ---------------------------------------------------------------------------------------------


GOOD = {
    "name": "mini", "conditions": ["visual", "touch"],
    "tasks": [{"id": "looks", "kind": "look-alikes", "prompt": "?", "options": ["convex", "flat"],
               "stimuli": [{"answer": "convex", "scene": "config/scenes/convex-front.yaml"},
                           {"answer": "flat", "scene": "config/scenes/flat-front.yaml"}]}],
}


def bad(change) -> ConfigError:
    data = msgspec.json.decode(msgspec.json.encode(GOOD))
    change(data)
    with pytest.raises(ConfigError) as info:
        parse_study(data, "study.yaml")
    assert info.value.file == "study.yaml"
    return info.value


def test_a_small_study_file_reads():
    study = parse_study(GOOD, "study.yaml")
    assert study.counterbalancing() == "all" and study.repetitions == 1
    assert [t.stimulus for t in plan_session(study, "P01")] != []


def test_bad_study_files_name_file_key_expected_and_got():
    e = bad(lambda d: d["tasks"][0].update(optoins=["a"]))
    assert e.key == "tasks[0].optoins" and "did you mean 'options'?" in str(e)
    e = bad(lambda d: d.update(repetitions=0))
    assert e.key == "repetitions" and e.got == 0 and ">= 1" in e.expected
    e = bad(lambda d: d.update(conditions=["visual", "smell"]))
    assert e.key == "conditions[1]" and e.got == "smell" and "visual+touch" in e.expected
    e = bad(lambda d: d["tasks"][0]["stimuli"][1].update(answer="hollow"))
    assert e.key == "tasks[0].stimuli[1].answer" and e.got == "hollow" and "convex, flat" in e.expected
    e = bad(lambda d: d["tasks"][0]["stimuli"][0].update(scene="config/scenes/no-such.yaml"))
    assert e.key == "tasks[0].stimuli[0].scene" and "scene file" in e.expected
    e = bad(lambda d: d["tasks"][0].update(kind="tilt"))
    assert e.key == "tasks[0].stimuli" and "tilt" in e.expected
    e = bad(lambda d: d["tasks"][0].update(kind="tilted"))
    assert e.key == "tasks[0].kind" and e.got == "tilted" and "did you mean 'tilt'?" in str(e)
    assert e.expected == "one of front-element, look-alikes, tilt"
    e = bad(lambda d: d["tasks"][0].update(jitter_planes=["xq"]))
    assert e.key == "tasks[0].jitter_planes[0]" and e.got == "xq"
    e = bad(lambda d: d["tasks"].append(dict(d["tasks"][0])))
    assert e.key == "tasks[1].id" and e.got == "looks"


def test_a_bad_tilt_task_is_named(tmp_path):
    tilt = {"id": "t", "kind": "tilt", "prompt": "?", "options": ["left", "right"], "scene": "config/scenes/hypercube.yaml",
            "angles_deg": [2, 4], "positive": "up"}
    with pytest.raises(ConfigError) as info:
        parse_study({"name": "x", "tasks": [tilt]}, "s.yaml")
    assert info.value.key == "tasks[0].positive" and info.value.got == "up"
    with pytest.raises(ConfigError) as info:
        parse_study({"name": "x", "tasks": [{**tilt, "positive": "left", "angles_deg": [2, 90]}]}, "s.yaml")
    assert info.value.key == "tasks[0].angles_deg[1]" and info.value.got == 90


def test_no_break_comes_just_before_the_break_between_blocks(paper):
    # 71 trials a block: every 34 would pause before trial 34 and again 3 trials before the block's end
    study = replace_study(paper, break_every=34)
    for block in range(3):
        trials = [t for t in plan_session(study, "P01") if t.block == block]
        assert len(trials) == 71
        assert [t.trial for t in trials if t.break_before] == [34]
    every24 = [t.trial for t in plan_session(replace_study(paper, break_every=24), "P01") if t.block == 0
               and t.break_before]
    assert every24 == [24, 48]               # 23 trials left after the second: half a stretch or more
