"""The desktop tracker's fingers: keys 1 .. 5 curl thumb .. little, f makes a fist, v spreads."""
import numpy as np
import pytest

from test_tracking_desktop import DT, hand_at_origin, run


def test_a_held_key_curls_its_finger_at_the_set_speed_and_release_straightens_it():
    hand = hand_at_origin(curl_speed=2.0)
    run(hand, 0.25, keys=["2"])                      # index: half curled after a quarter second at 2 / s
    assert hand.shape.of("index") == pytest.approx(0.5)
    assert all(hand.shape.of(f) == 0.0 for f in ("thumb", "middle", "ring", "little"))
    run(hand, 1.0, keys=["2", "5"], start=1.0)
    assert hand.shape.of("index") == 1.0 and hand.shape.of("little") == 1.0     # at most fully curled
    run(hand, 0.25, keys=[], start=3.0)
    assert hand.shape.of("index") == pytest.approx(0.5) and hand.shape.of("little") == pytest.approx(0.5)


def test_f_makes_a_fist_and_v_spreads_and_moving_still_works():
    hand = hand_at_origin(curl_speed=4.0, move_speed=0.5)
    sample = run(hand, 1.0, keys=["f", "v", "d"])
    assert all(hand.shape.of(f) == 1.0 for f in ("thumb", "index", "middle", "ring", "little"))
    assert hand.shape.spread == 1.0
    assert np.allclose(sample.position, [0.5, 0.0, 0.0])
    # stale input counts as released: the fingers open again
    for k in range(int(2.5 / DT)):
        hand.step(DT, 10.0 + k * DT)
    assert hand.shape.of("index") == 0.0 and hand.shape.spread == 0.0
