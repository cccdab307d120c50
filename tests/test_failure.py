import numpy as np
import pytest

from box_core import failure_value, fill_failures


def test_magnitude_rule_puts_failures_below_every_feasible_score():
    D = np.array([[-5.0, -1.0], [-2.0, 99.0]])
    F = np.array([[True, True], [True, False]])
    # feasible scores -5, -1, -2: min -5, mean -8/3
    assert failure_value(D, F) == pytest.approx(-5 - 8 / 3)
    assert failure_value(D, F) < D[F].min()


def test_literal_rule_follows_the_paper_even_when_it_lands_above_the_minimum():
    D = np.array([[-5.0, -1.0, 0.0]])
    F = np.array([[True, True, True]])
    assert failure_value(D, F, rule="literal") == pytest.approx(-5 - (-2))
    assert failure_value(D, F, rule="literal") > -5


def test_magnitude_rule_with_zero_mean_still_separates_failures():
    D = np.array([[-1.0, 1.0]])
    assert failure_value(D, np.ones((1, 2), bool)) == pytest.approx(-2.0)


def test_fill_failures_only_touches_infeasible_entries():
    D = np.array([[1.0, 2.0], [3.0, 4.0]])
    F = np.array([[True, False], [False, True]])
    np.testing.assert_array_equal(fill_failures(D, F, -9.0), [[1.0, -9.0], [-9.0, 4.0]])


@pytest.mark.parametrize("kwargs, message", [
    ({"feasible": np.zeros((2, 2), bool)}, "no feasible"),
    ({"feasible": np.ones((2, 3), bool)}, "shape"),
    ({"feasible": np.ones((2, 2), bool), "rule": "paper"}, "unknown failure rule"),
])
def test_failure_value_rejects_bad_input(kwargs, message):
    with pytest.raises(ValueError, match=message):
        failure_value(np.zeros((2, 2)), **kwargs)
