"""Study task kinds: each kind one class (touch4d.study.design), its stimuli, scenes, trials and rows the
paper's rules make of the study file; a file's mistakes named by key for the kind it names; a new kind
added by defining one subclass."""
import collections
import json
import math
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import yaml

from touch4d.errors import ConfigError
from touch4d.study.design import load_study, parse_study
from touch4d.study.plan import plan_session
from touch4d.study.stimuli import scene_mapping, stimulus_scene_path
from touch4d.study.table import trial_row

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "config/studies/paper.yaml"


@pytest.fixture(scope="module")
def paper_file():
    """The paper's study file as YAML gives it: what the expectations below are derived from."""
    return yaml.safe_load(PAPER.read_text())


@pytest.fixture(scope="module")
def paper():
    return load_study(PAPER)


def expected_stimuli(task: dict) -> list[tuple[str, float, str]]:
    """(name, level, answer) of a task's stimuli by the file and the paper's rules: a listed task's
    stimuli as listed (named by their answer); a tilt task's angles each with both signs, negative
    first from the largest, named tilt+8 / tilt-2, a positive level answering `positive` (Fig. 18: a
    cell tilted to the left is felt stronger on the right) and a negative one the other option."""
    if task["kind"] != "tilt":
        return [(s.get("name", s["answer"]), math.nan, s["answer"]) for s in task["stimuli"]]
    other = next(o for o in task["options"] if o != task["positive"])
    angles = sorted(task["angles_deg"])
    levels = [-a for a in reversed(angles)] + angles
    return [(f"tilt{'+' if v > 0 else '-'}{abs(v):g}", float(v), task["positive"] if v > 0 else other) for v in levels]


def same(a: float, b: float) -> bool:
    return (math.isnan(a) and math.isnan(b)) or a == b


def test_each_kind_of_the_paper_reads_as_its_own_class(paper, paper_file):
    kinds = {t["id"]: t["kind"] for t in paper_file["tasks"]}
    assert kinds == {"front": "front-element", "lookalikes": "look-alikes", "tilt": "tilt"}
    got = {t.id: (t.kind, type(t).__name__) for t in paper.tasks}
    assert got == {"front": ("front-element", "FrontElementTask"), "lookalikes": ("look-alikes", "LookAlikesTask"),
                   "tilt": ("tilt", "TiltTask")}


def test_each_kinds_stimuli_and_scene_files_follow_the_study_file(paper, paper_file):
    for spec in paper_file["tasks"]:
        task = paper.task(spec["id"])
        wanted = expected_stimuli(spec)
        got = [tuple(s) for s in task.stimulus_set()]
        assert [(n, a) for n, _, a in got] == [(n, a) for n, _, a in wanted], spec["id"]
        assert all(same(g[1], w[1]) for g, w in zip(got, wanted)), spec["id"]
        scenes = {s.get("name", s["answer"]): s["scene"] for s in spec.get("stimuli", [])}
        for name, _, _ in wanted:
            assert stimulus_scene_path(paper, spec["id"], name) == ROOT / scenes.get(name, spec.get("scene"))
    assert len(expected_stimuli(next(t for t in paper_file["tasks"] if t["kind"] == "tilt"))) == 8


def test_a_plan_holds_each_kinds_stimuli_with_their_answers_turns_and_rows(paper, paper_file):
    trials = plan_session(paper, "P01")
    main = [t for t in trials if not t.practice]
    counts = collections.Counter((t.condition, t.task, t.stimulus) for t in main)
    for spec in paper_file["tasks"]:
        repetitions = spec.get("repetitions", paper_file["repetitions"])
        for condition in paper_file["conditions"]:
            for name, _, _ in expected_stimuli(spec):
                assert counts.pop((condition, spec["id"], name)) == repetitions
    assert not counts                                      # nothing else planned
    by_task = {t["id"]: t for t in paper_file["tasks"]}
    for trial in trials:
        spec = by_task[trial.task]
        name, level, answer = next(s for s in expected_stimuli(spec) if s[0] == trial.stimulus)
        assert (trial.kind, trial.answer, trial.options, trial.prompt) == (spec["kind"], answer, spec["options"],
                                                                           spec["prompt"])
        assert same(trial.level, level)
        # Each object of the stimulus's scene file turned as the file says, then by the kind's own turn (a
        # tilt task's: its level in its plane), then by the jitter.
        scene = next((s["scene"] for s in spec.get("stimuli", []) if s.get("name", s["answer"]) == name), None)
        objects = yaml.safe_load((ROOT / (scene or spec.get("scene"))).read_text())["objects"]
        jitter = [[plane, deg] for plane, deg in trial.transform]
        tilt = [[spec["plane"], level]] if spec["kind"] == "tilt" else []
        mapping = scene_mapping(paper, trial)
        assert [obj["rotation"] for obj in mapping["objects"]] == [obj.get("rotation", []) + tilt + jitter
                                                                   for obj in objects]
        assert all(abs(deg) <= spec["jitter_deg"] for _, deg in trial.transform)
        assert {plane for plane, _ in trial.transform} <= set(spec.get("jitter_planes", ["xy", "xz", "xw", "yz",
                                                                                          "yw", "zw"]))
        row = trial_row(trial, participant="P01", session="s", response=answer, onset=1.0, response_stamp=2.5,
                        time_touching_s=0.0, mean_intensity=0.0, path_length=0.0)
        assert (row["kind"], row["stimulus"], row["answer"], row["correct"]) == (spec["kind"], name, answer, True)
        assert same(row["level"], level) and json.loads(row["transform"]) == jitter


def study_with(task: dict) -> dict:
    return {"name": "x", "tasks": [task]}


LOOKS = {"id": "looks", "kind": "look-alikes", "prompt": "?", "options": ["convex", "flat"],
         "stimuli": [{"answer": "convex", "scene": "config/scenes/convex-front.yaml"},
                     {"answer": "flat", "scene": "config/scenes/flat-front.yaml"}]}
TILT = {"id": "t", "kind": "tilt", "prompt": "?", "options": ["left", "right"], "scene": "config/scenes/hypercube.yaml",
        "angles_deg": [2, 4]}


@pytest.mark.parametrize("task, key, words, got", [
    ({**LOOKS, "plane": "xy"}, "plane", ["no plane for kind look-alikes", "a key of kind tilt"], "xy"),
    ({**LOOKS, "scene": "config/scenes/hypercube.yaml"}, "scene", ["no scene for kind look-alikes", "kind tilt"],
     "config/scenes/hypercube.yaml"),
    ({**TILT, "stimuli": LOOKS["stimuli"]}, "stimuli", ["no stimuli for kind tilt", "front-element and look-alikes"],
     LOOKS["stimuli"]),
    ({k: v for k, v in LOOKS.items() if k != "kind"}, "kind",
     ["one of front-element, look-alikes, tilt", "required"], None),
    ({k: v for k, v in TILT.items() if k != "scene"}, "scene", ["untilted scene", "required"], None),
    ({**TILT, "angles_deg": []}, "angles_deg", ["non-empty list of tilt angles"], []),
    ({**TILT, "angles_deg": [2, 2]}, "angles_deg", ["each angle once"], [2.0, 2.0]),
    ({**TILT, "options": ["a", "b", "c"]}, "options", ["two options for a tilt task"], ["a", "b", "c"]),
    ({**TILT, "plane": "xq"}, "plane", ["a rotation plane"], "xq"),
    ({**LOOKS, "stimuli": LOOKS["stimuli"][:1]}, "stimuli", ["at least two stimuli"], LOOKS["stimuli"][:1]),
    ({**LOOKS, "stimuli": [LOOKS["stimuli"][0]] * 2}, "stimuli[1].name", ["a stimulus name not used"], "convex"),
    ({**TILT, "angels_deg": [2]}, "angels_deg", ["one of the keys of kind tilt", "angles_deg"], None),
])
def test_a_bad_task_is_named_by_file_key_and_its_kind(task, key, words, got):
    with pytest.raises(ConfigError) as info:
        parse_study(study_with(task), "study.yaml")
    e = info.value
    assert (e.file, e.key, e.got) == ("study.yaml", f"tasks[0].{key}", got), str(e)
    assert all(w in str(e) for w in words), str(e)


TOY_KIND = textwrap.dedent('''
    import json, math
    from typing import Annotated
    import msgspec
    from touch4d.study.design import Stimulus, Task, kind_class, parse_study, task_kinds
    from touch4d.study.plan import plan_session
    from touch4d.study.stimuli import scene_mapping
    from touch4d.errors import ConfigError

    class SpinTask(Task, tag="spin", kw_only=True):
        """Is the object turned a little or a lot in yw? (a kind made for this test)"""
        scene: str
        spins_deg: Annotated[list[float], msgspec.Meta(min_length=1)]

        def stimulus_set(self):
            return [Stimulus(f"spin{a:g}", float(a), self.options[0] if a < 10 else self.options[1])
                    for a in self.spins_deg]

        def scene_files(self):
            return [("scene", self.scene)]

        def scene_of(self, stimulus):
            return ("scene", self.scene)

        def turns(self, level):
            return [["yw", level]]

    spin = {"id": "spin", "kind": "spin", "prompt": "?", "options": ["little", "lot"],
            "scene": "config/scenes/hypercube.yaml", "spins_deg": [5, 20]}
    study = parse_study({"name": "toy", "conditions": ["visual"], "tasks": [spin]}, "toy.yaml")
    trials = plan_session(study, "P01")
    out = {"kinds": list(task_kinds()), "class": kind_class("spin").__name__,
           "trials": sorted((t.kind, t.stimulus, t.level, t.answer) for t in trials),
           "rotations": sorted(scene_mapping(study, t)["objects"][0]["rotation"][0][1] for t in trials)}
    for bad in ({**spin, "spins": [5]}, {**spin, "kind": "spun"}, {**spin, "spins_deg": []}):
        try:
            parse_study({"name": "toy", "tasks": [bad]}, "toy.yaml")
        except ConfigError as exc:
            out.setdefault("errors", []).append([exc.key, exc.expected])

    class HalfTask(Task, tag="half", kw_only=True):   # a kind that forgot its scenes: said at once, by name
        def stimulus_set(self):
            return []
    try:
        task_kinds()
    except TypeError as exc:
        out["half"] = str(exc)
    print(json.dumps(out))
''')


def test_a_new_kind_is_one_subclass_that_study_files_and_plans_take_up():
    # In a process of its own: a kind defined here would stay defined for every later test.
    done = subprocess.run([sys.executable, "-c", TOY_KIND], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    assert out["kinds"] == ["front-element", "look-alikes", "tilt", "spin"] and out["class"] == "SpinTask"
    assert out["trials"] == [["spin", "spin20", 20.0, "lot"], ["spin", "spin5", 5.0, "little"]]
    assert out["rotations"] == [5.0, 20.0]                 # the kind's own turn, in yw, by each level
    assert out["errors"][0][0] == "tasks[0].spins" and "one of the keys of kind spin" in out["errors"][0][1]
    assert out["errors"][1] == ["tasks[0].kind", "one of front-element, look-alikes, tilt, spin"]
    assert out["errors"][2][0] == "tasks[0].spins_deg" and "length >= 1" in out["errors"][2][1]
    assert "HalfTask ('half') defines no scene_files, scene_of" in out["half"]
