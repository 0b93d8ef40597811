"""Tests of pedx_graph/small_arrays.py: the low-overhead median gives np.median's values, bit for bit."""
import numpy as np
import pytest

from pedx_graph.small_arrays import median


def _same(ours, numpys) -> bool:
    return np.shape(ours) == np.shape(numpys) and np.array_equal(ours, numpys, equal_nan=True)


@pytest.mark.parametrize("seed", [0, 1])
def test_median_is_numpys_bit_for_bit(seed):
    """Odd and even counts, repeated values, infinities, NaN, integers and lists, at scales from 1e-3 to 1e3:
    the same value and type as ``np.median`` (the even case is the two middle values' sum over two, as
    ``np.mean`` forms it)."""
    rng = np.random.default_rng(seed)
    for _ in range(3000):
        n = int(rng.integers(1, 25))
        x = rng.normal(size=n) * 10 ** rng.uniform(-3, 3)
        if rng.random() < 0.3:
            x = np.round(x, 1)
        if rng.random() < 0.1:
            x[rng.integers(n)] = rng.choice([np.inf, -np.inf])
        if rng.random() < 0.1:
            x[rng.integers(n)] = np.nan
        for values in (x, list(x), rng.integers(-9, 9, size=n)):
            ours, numpys = median(values), np.median(values)
            assert type(ours) is type(numpys)
            assert _same(ours, numpys), values


def test_median_along_an_axis_is_numpys():
    """Along either axis of a 2-D array, a NaN spoiling only its own slice."""
    rng = np.random.default_rng(2)
    for _ in range(300):
        a = rng.normal(size=(int(rng.integers(1, 6)), int(rng.integers(1, 12))))
        if rng.random() < 0.3:
            a[rng.integers(a.shape[0]), rng.integers(a.shape[1])] = np.nan
        for axis in (None, 0, 1):
            assert _same(median(a, axis=axis), np.median(a, axis=axis))


def test_median_of_nothing_is_left_to_numpy():
    with pytest.warns(RuntimeWarning):
        assert np.isnan(median(np.zeros(0)))
