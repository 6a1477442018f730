"""Oracle tests of the running observation normaliser (`core.normalize.RunningMeanStd`): the
parallel mean/variance merge of Chan, Golub & LeVeque (1979) must equal np.mean / np.var over
everything seen, and `normalize` must compute clip((x − mean)/std, ±clip)."""

import math

import numpy as np
import pytest

from quadpilot.core.normalize import RunningMeanStd

RNG = np.random.default_rng(7)
# batches of different sizes, means and spreads (the merge's δ² term matters), one of a single row
BATCHES = [
    RNG.normal([0.0, 5.0, -3.0], [1.0, 0.1, 4.0], size=(7, 3)),
    RNG.normal([2.0, -1.0, 10.0], [3.0, 2.0, 0.5], size=(50, 3)),
    np.array([[100.0, -100.0, 0.0]]),
    RNG.normal([-4.0, 0.0, 1.0], [0.2, 7.0, 1.0], size=(13, 3)),
]


def test_running_statistics_equal_numpy_over_the_concatenation():
    """With a negligible prior count the merged statistics are those of all rows at once."""
    rms = RunningMeanStd((3,), epsilon=1e-12)
    for b in BATCHES:
        rms.update(b)
    x = np.concatenate(BATCHES)
    np.testing.assert_allclose(rms.mean, x.mean(axis=0), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(rms.var, x.var(axis=0), rtol=1e-9)  # population variance, ddof = 0
    assert rms.count == pytest.approx(len(x), abs=1e-9)


def test_the_default_prior_is_a_pseudo_sample_of_weight_epsilon():
    """The default count 1e-4 starts from mean 0, variance 1: the result is the weighted pooled
    mean and variance of that prior and the data, exactly."""
    eps = 1e-4
    rms = RunningMeanStd((3,))
    for b in BATCHES:
        rms.update(b)
    x = np.concatenate(BATCHES)
    n = len(x) + eps
    mean = x.sum(axis=0) / n
    var = (eps * (1.0 + mean**2) + ((x - mean) ** 2).sum(axis=0)) / n
    np.testing.assert_allclose(rms.mean, mean, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(rms.var, var, rtol=1e-10)


def test_hand_values_of_a_two_batch_merge():
    """Batches {1, 3} and {5}: mean 3, population variance ((1−3)² + 0 + (5−3)²)/3 = 8/3."""
    rms = RunningMeanStd((1,), epsilon=1e-12)
    rms.update(np.array([[1.0], [3.0]]))
    np.testing.assert_allclose(rms.mean, [2.0], atol=1e-9)
    np.testing.assert_allclose(rms.var, [1.0], atol=1e-9)
    rms.update(np.array([[5.0]]))
    np.testing.assert_allclose(rms.mean, [3.0], atol=1e-9)
    np.testing.assert_allclose(rms.var, [8.0 / 3.0], atol=1e-9)


def test_normalize_subtracts_the_mean_and_divides_by_the_std():
    rms = RunningMeanStd((3,))
    rms.load_state_dict(
        {"mean": np.array([1.0, -2.0, 0.5]), "var": np.array([4.0, 0.25, 1.0]), "count": 10.0, "clip": 10.0}
    )
    x = np.array([[3.0, -1.0, 0.5], [-1.0, -3.0, 2.5]])
    # (3 − 1)/2 = 1, (−1 + 2)/0.5 = 2, 0;  (−1 − 1)/2 = −1, (−3 + 2)/0.5 = −2, 2/1 = 2   (std = √(var + 1e-8))
    out = rms.normalize(x)
    assert out.dtype == np.float32
    np.testing.assert_allclose(out, [[1.0, 2.0, 0.0], [-1.0, -2.0, 2.0]], rtol=1e-6, atol=1e-7)
    assert rms.std[0] == pytest.approx(math.sqrt(4.0 + 1e-8), rel=1e-15)


def test_normalize_clips_at_plus_minus_clip():
    rms = RunningMeanStd((2,), clip=5.0)
    rms.load_state_dict({"mean": np.zeros(2), "var": np.ones(2), "count": 10.0, "clip": 5.0})
    out = rms.normalize(np.array([[100.0, -100.0], [4.0, -4.5]]))
    np.testing.assert_allclose(out, [[5.0, -5.0], [4.0, -4.5]], rtol=1e-6)
    default = RunningMeanStd((1,))
    assert default.normalize(np.array([[1e6]]))[0, 0] == pytest.approx(10.0)
    assert default.normalize(np.array([[-1e6]]))[0, 0] == pytest.approx(-10.0)


def test_normalised_data_has_zero_mean_and_unit_variance():
    rms = RunningMeanStd((3,), epsilon=1e-12)
    x = np.concatenate(BATCHES[:2] + BATCHES[3:])  # without the outlier row: nothing clips
    rms.update(x)
    z = rms.normalize(x).astype(np.float64)
    np.testing.assert_allclose(z.mean(axis=0), 0.0, atol=1e-5)
    np.testing.assert_allclose(z.var(axis=0), 1.0, rtol=1e-5)


def test_non_finite_rows_are_not_merged():
    rms = RunningMeanStd((2,), epsilon=1e-12)
    rms.update(np.array([[1.0, 2.0], [np.nan, 0.0], [3.0, np.inf], [3.0, 4.0]]))
    np.testing.assert_allclose(rms.mean, [2.0, 3.0], atol=1e-9)
    np.testing.assert_allclose(rms.var, [1.0, 1.0], atol=1e-9)
    assert rms.count == pytest.approx(2.0)


def test_float32_observations_are_accumulated_in_float64():
    """Observations arrive as float32; the statistics are float64 sums. {1e8, 1, −1e8} has mean 1/3
    and population variance (2·1e16 + 1 − 1/9·3)/3 ≈ 6.6667e15; summed in float32, 1e8 + 1 rounds
    back to 1e8 and the mean comes out 0."""
    rms = RunningMeanStd((1,), epsilon=1e-12)
    rms.update(np.array([[1e8], [1.0], [-1e8]], np.float32))
    np.testing.assert_allclose(rms.mean, [1.0 / 3.0], rtol=1e-9)
    np.testing.assert_allclose(rms.var, [(2e16 + 1.0) / 3.0 - 1.0 / 9.0], rtol=1e-12)


# statistics as a float32 checkpoint might hold them: 0.1f = 0.100000001490116…, 9 exactly
F32_STATE = {"mean": np.float32([0.1]), "var": np.float32([9.0]), "count": 10, "clip": 100}


def test_loaded_float32_statistics_normalise_in_float64():
    """A float32 mean read from a checkpoint is held in float64: x − mean is not rounded to float32
    before the division (that double rounding changes the last bit of ~1/3 of outputs)."""
    rms = RunningMeanStd((1,))
    rms.load_state_dict(F32_STATE)
    x = np.float32([[62.65405], [21.327156], [45.89931]])
    expected = ((x.astype(np.float64) - float(np.float32(0.1))) / math.sqrt(9.0 + 1e-8)).astype(np.float32)
    np.testing.assert_array_equal(rms.normalize(x), expected)


def test_loaded_float32_variance_and_count_merge_in_float64():
    """After loading var = 0.1f (0.100000001490116…) at count 10, one sample at the mean leaves the
    mean and gives var = 10·0.1f/11 = 0.0909090922637…; var·count in float32 rounds 1.0000000149 to 1."""
    rms = RunningMeanStd((1,))
    rms.load_state_dict({"mean": [0.0], "var": np.float32([0.1]), "count": 10, "clip": 10})
    rms.update(np.zeros((1, 1)))
    np.testing.assert_allclose(rms.mean, [0.0], atol=0)
    np.testing.assert_allclose(rms.var, [10.0 * float(np.float32(0.1)) / 11.0], rtol=1e-14)
    assert rms.count == 11.0


def test_state_dict_round_trip_holds_the_numbers_as_copies():
    rms = RunningMeanStd((2,), epsilon=1e-12, clip=4.0)
    rms.update(np.array([[1.0, 10.0], [3.0, 20.0]]))
    d = rms.state_dict()
    np.testing.assert_allclose(d["mean"], [2.0, 15.0], atol=1e-9)
    np.testing.assert_allclose(d["var"], [1.0, 25.0], atol=1e-9)
    assert d["count"] == pytest.approx(2.0, abs=1e-9)
    assert d["clip"] == 4.0
    d["mean"][:] = 0.0  # a copy: the live statistics are not changed through it
    np.testing.assert_allclose(rms.mean, [2.0, 15.0], atol=1e-9)
    restored = RunningMeanStd((2,))
    restored.load_state_dict(rms.state_dict())
    x = np.array([[0.0, 40.0]])  # (0 − 2)/1 = −2, (40 − 15)/5 = 5 → clipped to 4
    np.testing.assert_allclose(restored.normalize(x), [[-2.0, 4.0]], rtol=1e-6)
