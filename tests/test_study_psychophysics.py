"""The observer's touch noise set from human data: a two-interval amplitude discrimination run
through the observer's noise lands inside the published fingertip range (2.2-2.5 dB) and, at the
thenar's noise, near its 0.2, and agrees with the closed form; the earlier guessed noise (0.08) is
sharper than people are. Where a vibration is felt: the localisation task's mean error agrees with
the Rayleigh mean sd sqrt(pi/2)."""
import math

import pytest

from touch4d.study.power import Population
from touch4d.study.psychophysics import (FINGERTIP_WEBER_DB, HUMAN_NOISE, THENAR_NOISE, THENAR_WEBER,
                                         amplitude_discrimination, db_from_weber, noise_for_weber,
                                         vibration_localisation, weber_from_db)


def test_the_default_observer_discriminates_amplitude_as_a_fingertip_does():
    measured = amplitude_discrimination(HUMAN_NOISE, trials=1500, seed=1)
    low, high = FINGERTIP_WEBER_DB
    assert low <= measured["weber_db"] <= high, measured
    assert Population().noise == HUMAN_NOISE


@pytest.mark.parametrize("noise", [0.05, 0.08, 0.12])
def test_the_simulated_weber_fraction_matches_the_closed_form(noise):
    # closed form: 75% correct at d = noise sqrt(2) Phi^-1(0.75) = 0.9539 noise, over the reference 0.5
    expected = noise * math.sqrt(2) * 0.6744897501960817 / 0.5
    assert amplitude_discrimination(noise, trials=1500, seed=2)["weber_fraction"] == pytest.approx(expected, rel=0.1)


def test_the_guessed_noise_was_sharper_than_the_fingertip_and_the_thenar():
    assert db_from_weber(weber_from_db(2.3)) == pytest.approx(2.3)
    assert amplitude_discrimination(0.08, trials=1500, seed=3)["weber_db"] < FINGERTIP_WEBER_DB[0]
    assert 0.08 < noise_for_weber(THENAR_WEBER) < HUMAN_NOISE


def test_the_thenars_noise_discriminates_amplitude_near_its_published_fraction():
    measured = amplitude_discrimination(THENAR_NOISE, trials=1500, seed=4)
    assert measured["weber_fraction"] == pytest.approx(0.2, abs=0.03), measured


@pytest.mark.parametrize("sd_mm", [2.0, 8.0])
def test_localisation_error_is_the_rayleigh_mean_of_the_felt_positions_noise(sd_mm):
    # closed form: a 2D Gaussian of sd s per axis lies s sqrt(pi/2) from its centre on average,
    # s sqrt(2 ln 2) at the median
    palm = [[0.0, 0.0, -0.0125], [0.025, 0.025, -0.0125], [-0.025, -0.025, -0.0125]]
    measured = vibration_localisation(palm, sd_mm, trials=20000, seed=5)
    assert measured["mean_error_mm"] == pytest.approx(sd_mm * math.sqrt(math.pi / 2), rel=0.03)
    assert measured["median_error_mm"] == pytest.approx(sd_mm * math.sqrt(2 * math.log(2)), rel=0.04)
