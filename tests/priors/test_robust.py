"""The geometric median (Weiszfeld with Vardi-Zhang's step) on configurations whose answer is known."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import optimize

from toosicubix.priors.geometric_median import GeometricMedianOptions, distance_sum, geometric_median


def plain_weiszfeld_step(points: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Weiszfeld's unguarded step, for contrast: it divides by the distance to every point."""
    inv = 1.0 / np.linalg.norm(points - y, axis=1)
    return inv @ points / inv.sum()


def direct_minimum(points: np.ndarray, weights: np.ndarray | None = None) -> float:
    """The smallest objective a general-purpose minimiser (BFGS with the analytic gradient) finds."""
    w = np.ones(len(points)) if weights is None else weights

    def f(y):
        return distance_sum(points, y, w)

    def grad(y):
        diff = y - points
        return (w / np.linalg.norm(diff, axis=1)) @ diff

    # Shifted starts: the gradient is undefined on a data point, and these configurations put one at the mean.
    shift = 1e-2 * np.linspace(1.0, 2.0, points.shape[1])
    starts = [points.mean(axis=0) + shift, np.median(points, axis=0) + shift]
    return min(optimize.minimize(f, s, jac=grad, method="BFGS", options={"gtol": 1e-12}).fun for s in starts)


def test_symmetric_set_has_its_centre_as_median(rng):
    centre = np.array([1.5, -2.0, 0.25, 4.0])
    half = rng.normal(size=(15, 4))
    points = np.vstack([centre + half, centre - half])
    # Start far off so the iteration, not the start, finds the centre.
    result = geometric_median(points, x0=centre + np.array([30.0, -20.0, 10.0, 5.0]))
    assert result.converged and not result.at_data_point
    # The stopping rule (step <= 1e-12 x the data's scale, ~36) leaves an error of about step x q / (1 - q)
    # for a contraction q per step, below 1e-9 for any q < 0.96 (here q is about 0.5).
    np.testing.assert_allclose(result.median, centre, rtol=0, atol=1e-9)


def test_odd_collinear_points_have_the_middle_one_as_median(rng):
    direction = np.array([1.0, 2.0, -2.0]) / 3.0
    t = np.sort(rng.uniform(-5.0, 5.0, size=7))
    points = np.array([2.0, 1.0, 0.0]) + t[:, None] * direction
    result = geometric_median(points)
    assert result.converged and result.at_data_point
    # The median is a data point, returned exactly by the optimality test: 1e-12 is round-off.
    np.testing.assert_allclose(result.median, points[3], rtol=0, atol=1e-12)


def test_even_collinear_points_any_point_between_the_middle_two_is_optimal(rng):
    direction = np.array([0.6, 0.8])
    t = np.sort(rng.uniform(0.0, 10.0, size=6))
    points = t[:, None] * direction
    best = distance_sum(points, points[2])
    assert distance_sum(points, points[3]) == pytest.approx(best, rel=1e-12)  # the whole segment is optimal
    result = geometric_median(points, x0=np.array([3.0, -7.0]))
    # Check the objective, not the point (the segment is flat); 1e-9 relative is far above the stopping rule.
    assert result.objective == pytest.approx(best, rel=1e-9)
    s = result.median @ direction
    assert t[2] - 1e-9 <= s <= t[3] + 1e-9
    assert abs(result.median @ np.array([-0.8, 0.6])) < 1e-9  # on the line


def test_far_outliers_barely_move_the_median_but_drag_the_mean(rng):
    cluster = rng.normal(scale=0.1, size=(100, 2))
    outliers = np.array([100.0, 100.0]) + rng.normal(scale=1.0, size=(10, 2))
    points = np.vstack([cluster, outliers])
    median = geometric_median(points).median
    # 10 of 110 points far away shift the median by about 10/100 of the cluster's spread; half the
    # cluster's sigma (0.05) is a generous bound, while the mean moves ~9 m, 90 sigmas.
    assert np.linalg.norm(median - np.median(cluster, axis=0)) < 0.05
    assert np.linalg.norm(points.mean(axis=0)) > 5.0


def test_start_on_the_median_data_point_returns_it_where_plain_weiszfeld_gives_nan():
    angles = np.deg2rad([90.0, 210.0, 330.0])
    centre = np.array([1.3, -0.7])
    points = np.vstack([centre, centre + np.c_[np.cos(angles), np.sin(angles)]])
    with np.errstate(divide="ignore", invalid="ignore"):
        assert not np.all(np.isfinite(plain_weiszfeld_step(points, centre)))
    result = geometric_median(points, x0=centre)
    # The three unit pulls cancel (r ~ 1e-16 <= eta = 1): Vardi-Zhang stops at the centre at once.
    assert result.at_data_point and result.converged and result.iterations == 0
    np.testing.assert_array_equal(result.median, centre)
    assert result.objective == pytest.approx(3.0, rel=1e-12)


def test_mean_landing_on_a_data_point_that_is_not_the_median():
    # Integer points whose mean is exactly the data point (0, 0), where the other points pull with r = 1.79 > 1.
    points = np.array([[0.0, 0.0], [-3.0, 0.0], [1.0, 0.5], [1.0, -0.5], [1.0, 0.0]])
    np.testing.assert_array_equal(points.mean(axis=0), points[0])
    with np.errstate(divide="ignore", invalid="ignore"):
        assert not np.all(np.isfinite(plain_weiszfeld_step(points, points[0])))
    result = geometric_median(points)
    assert result.converged and np.all(np.isfinite(result.median))
    assert result.objective < distance_sum(points, points[0])  # the modified step left the data point
    # BFGS converges to ~1e-10 relative on this smooth objective away from the data points.
    assert result.objective <= direct_minimum(points) * (1 + 1e-9)


def test_heavy_data_point_is_the_median():
    points = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0], [0.3, 0.2]])
    weights = np.array([1.0, 1.0, 1.0, 1.0, 10.0])
    # The four light points pull with at most 4 < 10: the heavy point is optimal, from any start.
    for x0 in (None, points[4], np.array([-5.0, 3.0])):
        result = geometric_median(points, weights, x0=x0)
        assert result.at_data_point and result.converged
        np.testing.assert_array_equal(result.median, points[4])


def test_weights_equal_repeated_points(rng):
    points = rng.normal(size=(12, 3))
    counts = rng.integers(1, 5, size=12)
    weighted = geometric_median(points, counts.astype(float))
    repeated = geometric_median(np.repeat(points, counts, axis=0))
    # Both stop at a step of 1e-12 x scale on the same objective: they agree far better than 1e-9.
    np.testing.assert_allclose(weighted.median, repeated.median, rtol=0, atol=1e-9)
    assert weighted.objective == pytest.approx(repeated.objective, rel=1e-12)


def test_zero_weights_drop_their_points(rng):
    points = rng.normal(size=(8, 2))
    weights = np.array([1.0, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(geometric_median(points, weights).median, geometric_median(points[:5]).median,
                               rtol=0, atol=1e-12)


def test_one_point_and_two_points():
    one = geometric_median(np.array([[2.0, -1.0, 0.5]]))
    np.testing.assert_array_equal(one.median, [2.0, -1.0, 0.5])
    assert one.iterations == 0 and one.converged and one.objective == 0.0
    two = np.array([[0.0, 0.0], [3.0, 4.0]])
    result = geometric_median(two)
    # Every point of the segment is optimal with objective |x1 - x0| = 5.
    assert result.objective == pytest.approx(5.0, rel=1e-12)
    assert result.converged and np.all(np.isfinite(result.median))
    np.testing.assert_allclose(result.median, [1.5, 2.0], rtol=0, atol=1e-12)  # from the mean it stays there


def test_identical_points_return_that_point():
    result = geometric_median(np.tile([1.0, 2.0], (5, 1)))
    np.testing.assert_array_equal(result.median, [1.0, 2.0])
    assert result.at_data_point and result.iterations == 0


def test_matches_a_direct_minimisation_on_random_data(rng):
    points = rng.standard_t(df=2, size=(200, 5))
    result = geometric_median(points)
    assert result.converged
    assert result.objective <= direct_minimum(points) * (1 + 1e-9)


def test_iteration_cap_reports_no_convergence(rng):
    points = rng.normal(size=(50, 3))
    result = geometric_median(points, x0=np.full(3, 10.0), options=GeometricMedianOptions(max_iterations=2))
    assert not result.converged and result.iterations == 2


@pytest.mark.parametrize(("points", "weights", "message"), [
    (np.zeros((0, 3)), None, r"shape \(n, k\)"),
    (np.zeros(3), None, r"shape \(n, k\)"),
    (np.array([[0.0, np.nan]]), None, "finite points"),
    (np.zeros((3, 2)), np.ones(2), r"weights of shape \(3,\)"),
    (np.zeros((3, 2)), np.array([1.0, -1.0, 1.0]), "non-negative"),
    (np.zeros((3, 2)), np.zeros(3), "not all zero"),
])
def test_bad_input_raises_value_error(points, weights, message):
    with pytest.raises(ValueError, match=message):
        geometric_median(points, weights)


def test_bad_start_shape_raises():
    with pytest.raises(ValueError, match=r"x0 of shape \(2,\)"):
        geometric_median(np.eye(2), x0=np.zeros(3))
