"""Intensity -> duty (exponent, start threshold, maximum, deadband), the thermal limit, and the bus load."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import msgspec
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from touch4d.errors import ConfigError
from touch4d.boards.busload import bus_load, check_bus_load, frame_bits
from touch4d.boards.config import DutyConfig, ThermalConfig, load_glove_can
from touch4d.boards.duty import (
    ThermalState, duty_to_levels, intensity_to_duty, levels_to_duty, thermal_deadline, thermal_limit,
)

DUTY = DutyConfig(exponent=2.0, start=0.3, max=0.8, deadband=0.05, full_scale=1.0)


def test_zero_and_deadband_are_off_and_any_felt_intensity_starts_the_motor():
    d = intensity_to_duty([0.0, 0.04, 0.05, 0.06], DUTY)
    assert d[0] == 0 and d[1] == 0
    assert d[2] == pytest.approx(0.3 + 0.5 * 0.05 ** 2)
    assert d[3] >= DUTY.start


def test_full_scale_gives_max_and_more_is_clipped_to_max():
    d = intensity_to_duty([1.0, 3.0, np.inf, np.nan], DUTY)
    assert d[0] == pytest.approx(0.8) and d[1] == pytest.approx(0.8)
    assert d[2] == 0 and d[3] == 0  # non-finite intensities are off, not full power


def test_exponent_shapes_the_curve_and_it_is_monotonic():
    x = np.linspace(0.05, 1, 50)
    d = intensity_to_duty(x, DUTY)
    assert np.all(np.diff(d) > 0)
    assert d[len(x) // 2] == pytest.approx(0.3 + 0.5 * x[len(x) // 2] ** 2)
    linear = intensity_to_duty(0.5, msgspec.structs.replace(DUTY, exponent=1.0))
    assert linear == pytest.approx(0.55)


def test_full_scale_scales_the_intensity():
    d = intensity_to_duty([2.0], msgspec.structs.replace(DUTY, full_scale=4.0, exponent=1.0))
    assert d[0] == pytest.approx(0.3 + 0.5 * 0.5)


def test_levels_quantize_to_seven_bits():
    lv = duty_to_levels([0.0, 1.0, 0.5, 1.2, -1.0, 0.3])
    assert lv.tolist() == [0, 127, 64, 127, 0, 38]
    assert np.all(np.abs(levels_to_duty(lv[:3]) - [0, 1, 0.5]) <= 0.5 / 127)


THERMAL = ThermalConfig(max_on_s=2.0, cool_s=1.0)


def run(duty_fn, times):
    state = ThermalState.initial(1)
    out = []
    for t in times:
        d, state = thermal_limit(np.array([duty_fn(t)]), state, t, THERMAL)
        out.append(d[0])
    return np.array(out)


def test_thermal_limit_forces_a_cool_down_after_the_continuous_on_time():
    t = np.arange(0, 6, 0.01)
    d = run(lambda _: 0.5, t)
    assert np.all(d[t < 1.99] == 0.5)
    assert np.all(d[(t > 2.01) & (t < 2.99)] == 0)
    assert np.all(d[(t > 3.01) & (t < 4.99)] == 0.5)  # back on after cool_s, for another max_on_s
    assert np.all(d[(t > 5.01) & (t < 5.99)] == 0)


def test_a_short_break_does_not_reset_the_on_time_but_a_full_rest_does():
    t = np.arange(0, 4, 0.01)
    short = run(lambda s: 0.0 if 1.0 <= s < 1.2 else 0.5, t)
    assert np.all(short[(t > 2.01) & (t < 2.99)] == 0)  # 0.2 s off < cool_s: still tripped at 2 s
    rest = run(lambda s: 0.0 if 1.0 <= s < 2.1 else 0.5, t)
    assert np.all(rest[(t > 2.1) & (t < 4.0)] == 0.5)   # 1.1 s off >= cool_s: a new streak from 2.1 s


def test_motors_are_limited_independently():
    state = ThermalState.initial(2)
    for t in np.arange(0, 2.5, 0.01):
        d, state = thermal_limit(np.array([0.5, 0.5 if t > 1.0 else 0.0]), state, t, THERMAL)
    assert d.tolist() == [0.0, 0.5]


@settings(max_examples=200, deadline=None)
@given(wanted=st.lists(st.sampled_from([0.0, 0.4]), min_size=3, max_size=3),
       changes=st.lists(st.tuples(st.floats(0.0, 4.0), st.integers(0, 2)), max_size=6),
       max_on=st.sampled_from([0.0, 0.5, 2.0]), cool=st.sampled_from([0.0, 0.3, 1.0]))
def test_the_thermal_limit_holds_until_its_deadline(wanted, changes, max_on, cool):
    """Between calls at a deadline, the limit (duty and state) is what the call at the last one gave."""
    cfg = ThermalConfig(max_on_s=max_on, cool_s=cool)
    state, wanted = ThermalState.initial(3), np.array(wanted)
    flips = dict(changes)
    for t in np.round(np.arange(0.0, 5.0, 0.05), 6):
        if any(abs(t - at) < 0.025 for at in flips):   # the wanted duty changes now and then
            k = flips[min(flips, key=lambda at: abs(t - at))]
            wanted[k] = 0.4 - wanted[k]
        duty, state = thermal_limit(wanted, state, t, cfg)
        until = thermal_deadline(wanted, state, t, cfg)
        assert until >= t
        for later in (t + 0.3 * (until - t), np.nextafter(until, -np.inf)) if np.isfinite(until) else (t + 100.0,):
            if later > t:
                again, after = thermal_limit(wanted, state, later, cfg)
                assert again.tolist() == duty.tolist()
                for a, b in zip(after.__dict__.values(), state.__dict__.values()):
                    np.testing.assert_array_equal(a, b)


def test_frame_bits_with_worst_case_stuffing():
    assert frame_bits(8, stuffing=False) == 111
    assert frame_bits(8) == 111 + (34 + 64 - 1) // 4 == 135
    assert frame_bits(0) == 47 + 33 // 4
    with pytest.raises(ValueError):
        frame_bits(9)


def test_default_glove_bus_load_is_under_the_limit():
    cfg = load_glove_can()
    load = check_bus_load(cfg)
    # worst case 2 duty frames per refresh period (changes every half period)
    per_board = 2 * cfg.refresh_hz * 135 + cfg.status_hz * 115 + cfg.heartbeat_hz * 65
    assert load.bits_per_s == pytest.approx(len(cfg.boards) * per_board)
    assert load.fraction == pytest.approx(len(cfg.boards) * per_board / 500_000)
    assert load.fraction < 0.7
    # The default glove: 4 boards at 200 Hz on 500 kbit/s -> 225 720 bit/s, 45.1 % worst case.
    assert (len(cfg.boards), cfg.refresh_hz, cfg.bitrate) == (4, 200.0, 500_000)
    assert load.bits_per_s == 225_720 and round(100 * load.fraction, 1) == 45.1


def test_a_configuration_over_seventy_percent_is_refused():
    cfg = load_glove_can(Path(__file__).parent / "data" / "glove_can_test.yaml")
    slow = dataclasses.replace(cfg, bitrate=250_000)
    assert bus_load(slow).fraction > 0.7
    with pytest.raises(ConfigError, match="bus load <= 70 %"):
        check_bus_load(slow)
