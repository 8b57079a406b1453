"""Distinct rows through packed keys give exactly what np.unique(axis=0) gives, in its order."""

import numpy as np
import pytest

from reloc.rowkeys import count_unique_rows, first_unique_rows, row_keys


@pytest.mark.parametrize("seed", range(20))
def test_distinct_rows_are_those_of_np_unique(seed):
    rng = np.random.default_rng(seed)
    m, k = int(rng.integers(1, 4000)), int(rng.integers(1, 4))
    rows = rng.integers(-int(rng.integers(1, 40)), int(rng.integers(1, 40)), size=(m, k))
    assert count_unique_rows(rows) == len(np.unique(rows, axis=0))
    np.testing.assert_array_equal(first_unique_rows(rows), np.unique(rows, axis=0, return_index=True)[1])


def test_keys_keep_the_rows_lexicographic_order():
    rows = np.array([[0, 5, -1], [0, 5, 2], [-3, 9, 9], [0, -2, 7], [1, -9, -9], [0, 5, -1]])
    keys = row_keys(rows)
    order = np.lexsort(rows.T[::-1])
    assert np.all(np.diff(keys[order]) >= 0)
    assert keys[0] == keys[5] and len(set(keys.tolist())) == 5


def test_rows_too_wide_to_pack_fall_back_to_np_unique():
    rows = np.array([[-(2**40), 0, 2**40], [2**40, 1, -(2**40)], [-(2**40), 0, 2**40]])
    assert row_keys(rows) is None
    assert count_unique_rows(rows) == 2
    np.testing.assert_array_equal(first_unique_rows(rows), [0, 1])
    extreme = np.array([[np.iinfo(np.int64).min, 0], [np.iinfo(np.int64).max, 0], [np.iinfo(np.int64).min, 0]])
    assert row_keys(extreme) is None  # a span that int64 arithmetic would wrap
    np.testing.assert_array_equal(first_unique_rows(extreme), [0, 1])


def test_no_rows_and_bad_rows():
    assert count_unique_rows(np.zeros((0, 2), dtype=np.int64)) == 0
    assert len(first_unique_rows(np.zeros((0, 2), dtype=np.int64))) == 0
    with pytest.raises(ValueError, match="2-D integer array"):
        row_keys(np.zeros((3, 2)))
    with pytest.raises(ValueError, match="2-D integer array"):
        row_keys(np.arange(4))
