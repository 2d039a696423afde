"""`touch4d study check`: a glove that cannot tell a task by touch is warned of (the library's
`glove_task_warnings`, which a study server calls too), and what a participant reads (consent,
instructions) agrees with the plan: its minutes and each task's options."""
import pytest

from touch4d.cli import main
from touch4d.study.design import load_study, replace_study, study_text_warnings
from touch4d.study.infotransfer import glove_task_warnings
from touch4d.tactile import load_glove

QUEST = "config/gloves/quest-controller.yaml"


@pytest.fixture(scope="module")
def paper():
    return load_study("paper")


def test_a_glove_that_cannot_tell_the_tilt_is_warned_of(paper, capsys):
    warnings = glove_task_warnings(load_glove(QUEST), paper)
    # the controller's one motor at the grip: a tilt of the front cell changes nearly nothing it feels
    assert [w.split(":")[0] for w in warnings] == ["task tilt"], warnings
    assert "of 3.00 bits" in warnings[0] and "quest-controller.yaml" in warnings[0]
    assert main(["study", "check", "paper", "--glove", QUEST]) == 0
    out = capsys.readouterr().out
    assert "warning: task tilt: one touch with" in out and "warning: task lookalikes" not in out, out


def test_the_papers_glove_tells_every_task(paper):
    assert glove_task_warnings(load_glove(), paper) == []


def test_a_study_without_touch_needs_no_glove_check(paper):
    assert glove_task_warnings(load_glove(QUEST), replace_study(paper, conditions=["visual"])) == []


def test_the_packaged_consent_names_the_plans_minutes_and_the_instructions_every_option(paper, capsys):
    # 213 trials (front and look-alikes 3 stimuli x 6 repetitions x 3 conditions each, tilt 8 x 4 x 3,
    # 3 practice trials a block) at the 20 s time limit: 4260 s, 71 minutes
    assert "at most 71 minutes" in paper.consent and "{minutes}" not in paper.consent
    for task in paper.tasks:
        assert ", ".join(task.options[:-1]) + " or " + task.options[-1] in paper.instructions, task.id
    assert "A and B buttons" not in paper.instructions
    assert main(["study", "check", "paper"]) == 0
    out = capsys.readouterr().out
    assert "at most 71 min of trials" in out and "warning" not in out, out


def test_a_consent_or_instructions_that_disagree_with_the_plan_are_warned_of(paper):
    text = replace_study(paper, consent="It takes about 45 minutes.",
                         instructions="Answer with the A and B buttons.")
    warnings = study_text_warnings(text)
    assert len(warnings) == 2, warnings
    assert "consent says '45 minutes'" in warnings[0] and "at most 71 minutes" in warnings[0]
    assert "instructions name 2 answer buttons" in warnings[1] and "3 options" in warnings[1]


def test_placeholders_are_filled_from_the_plan(tmp_path, paper):
    import yaml

    data = yaml.safe_load(open("config/studies/paper.yaml"))
    data.update(consent="{minutes} minutes", instructions="{answers}", repetitions=1, practice=0, time_limit_s=60)
    for task in data["tasks"]:
        task.pop("repetitions", None)
    (tmp_path / "one.yaml").write_text(yaml.safe_dump(data))
    one = load_study(tmp_path / "one.yaml")
    # 3 + 3 + 8 stimuli once in each of 3 conditions, a minute each
    assert one.consent == "42 minutes"
    assert one.instructions == "face, edge or vertex; convex, flat or concave; left or right"
