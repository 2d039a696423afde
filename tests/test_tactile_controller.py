"""A held controller as a glove (config/gloves/quest-controller.yaml): one actuator that covers
samples, its intensity eq. 3 with that motor's weights (closed forms on known distances)."""
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from touch4d.errors import ConfigError
from touch4d.tactile.glove import DEFAULT_GLOVE, glove_from_dict, load_glove
from touch4d.tactile.stimulus import stimulus_at

ROOT = Path(__file__).resolve().parents[1]
CONTROLLER = ROOT / "config" / "gloves" / "quest-controller.yaml"


class KnownDistances:
    """A ray caster that answers the distances a test chose (the scene is not what is tested here)."""

    def __init__(self, l):
        self.l = np.asarray(l, float)

    def cast(self, positions):
        return self.l.copy(), np.where(np.isnan(self.l), -1, 0)


def _inside(glove):
    return np.zeros((len(glove.samples), 3))   # every sample at the screen's centre: all inside


@pytest.fixture(scope="module")
def controller():
    return load_glove(CONTROLLER)


def test_the_controller_glove_is_one_actuator_covering_the_whole_fist(controller):
    assert controller.motor_names == ["grip"]
    assert controller.motor_weights.shape == (1, len(controller.samples))
    # every sample covered, each with 1/K
    np.testing.assert_allclose(controller.motor_weights, 1.0 / len(controller.samples))
    assert (controller.alpha, controller.beta, controller.gamma) == (3.0, 0.5, 2.0)
    assert controller.hand.contains(controller.samples).all()


def test_a_flat_contact_in_front_of_the_whole_fist_is_full_drive(controller):
    # every l equal: s = 1 (eq. 1), h = 1 - 0.5 = 0.5 (eq. 2), V = 2 * mean(h) = 1 (eq. 3)
    st = stimulus_at(controller, KnownDistances(np.full(len(controller.samples), 0.4)), _inside(controller))
    np.testing.assert_allclose(st.V, [1.0])


def test_the_actuator_feels_the_share_of_the_hand_in_contact(controller):
    n = len(controller.samples)
    l = np.full(n, np.nan)
    touched = np.arange(0, n, 5)            # a fifth of the samples, all at one depth
    l[touched] = 0.3
    st = stimulus_at(controller, KnownDistances(l), _inside(controller))
    # touched: s = 1, h = 0.5; the rest 0; V = gamma * (k * 0.5) / n
    np.testing.assert_allclose(st.V, [2.0 * len(touched) * 0.5 / n])
    st = stimulus_at(controller, KnownDistances(np.full(n, np.nan)), _inside(controller))
    np.testing.assert_allclose(st.V, [0.0])


def test_a_covering_motor_beside_a_coin_motor():
    data = yaml.safe_load(DEFAULT_GLOVE.read_text())
    data["motors"] = [{"name": "coin", "position": [0.0, 0.0, -0.0125], "board": 1, "channel": 0},
                      {"name": "near", "position": [0.0, 0.0, -0.0125], "board": 1, "channel": 1,
                       "covers": {"radius": 0.03}}]
    glove = glove_from_dict(data, "two.yaml")
    near = np.linalg.norm(glove.samples - [0.0, 0.0, -0.0125], axis=1) <= 0.03
    assert 1 < near.sum() < len(glove.samples)
    l = np.full(len(glove.samples), np.nan)
    l[glove.motor_sample[0]] = 0.2           # one touched sample: s = 1, h = 1 - 0.5 * 1 = 0.5
    st = stimulus_at(glove, KnownDistances(l), _inside(glove))
    np.testing.assert_allclose(st.V, [0.5, 0.5 / near.sum()])
    np.testing.assert_allclose(glove.motor_weights[0], np.eye(len(glove.samples))[glove.motor_sample[0]])


def test_a_glove_without_covers_keeps_one_sample_per_motor():
    assert load_glove().motor_weights is None


def test_a_cover_that_reaches_no_sample_is_named():
    data = yaml.safe_load(CONTROLLER.read_text())
    data["motors"][0]["covers"] = {"radius": 1e-6}
    data["motors"][0]["position"] = [0.0, 0.0, 0.029]   # on the hand, yet farther than 1e-6 from every sample
    with pytest.raises(ConfigError, match=r"motors\[0\]\.covers\.radius"):
        glove_from_dict(data, "c.yaml")
    data["motors"][0]["covers"] = {"radius": -1}
    with pytest.raises(ConfigError, match="radius"):
        glove_from_dict(data, "c.yaml")


def test_study_transfer_compares_the_controller_beside_the_30_motor_glove(capsys):
    from touch4d.cli import main as cli_main

    rc = cli_main(["study", "transfer", "config/studies/paper.yaml", "--glove", "config/glove.yaml", "--glove",
                   str(CONTROLLER), "--task", "lookalikes", "--scenes", "4", "--positions", "4", "--json"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert [(Path(r["glove"]).name, r["motors"]) for r in out["results"]] == [("glove.yaml", 30),
                                                                              ("quest-controller.yaml", 1)]
    assert all(0 <= r["bits"] <= r["max_bits"] for r in out["results"])
