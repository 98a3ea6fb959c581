"""What switching between a front's policies reaches, and the points beyond it (the additive epsilon margin)."""

import pytest

from hddpg_zoo.benchmark.front_mixtures import mixture_shortfall, points_beyond

# Two gaits: fast and costly, still and free (speed and energy, both to maximise).
GAITS = [[1.0, 0.0], [0.0, 1.0]]


def test_a_point_beyond_the_segment_between_two_gaits_falls_short_by_its_margin():
    # The segment's midpoint is (0.5, 0.5): a blended gait at (0.6, 0.6) is 0.1 beyond it on both objectives.
    assert mixture_shortfall([0.6, 0.6], GAITS, [True, True]) == pytest.approx(0.1)


def test_points_a_mixture_reaches_have_no_margin():
    margins = points_beyond([[0.5, 0.5], [0.2, 0.3], [1.0, 0.0]], GAITS, [True, True])
    assert margins[0] == pytest.approx(0.0, abs=1e-9)
    assert margins[1] == pytest.approx(-0.25)  # every objective 0.25 short of the mix (0.45, 0.55)
    assert margins[2] == pytest.approx(0.0, abs=1e-9)


def test_objectives_to_minimise_count_the_other_way():
    # Energy as a cost: the same geometry with the second objective negated and minimised.
    costs = [[1.0, 0.0], [0.0, -1.0]]
    assert mixture_shortfall([0.6, -0.6], costs, [True, False]) == pytest.approx(0.1)


def test_one_point_front_and_mismatched_objectives():
    assert mixture_shortfall([0.0, 2.0], [[1.0, 1.0]], [True, True]) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="at least one front point"):
        mixture_shortfall([0.0, 1.0], [], [True, True])
    with pytest.raises(ValueError, match="at least one front point"):
        mixture_shortfall([0.0, 1.0], [[1.0, 1.0, 1.0]], [True, True])
