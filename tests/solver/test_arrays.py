import numpy as np
import pytest

from solver.arrays import evenly_spaced


@pytest.mark.parametrize("n, k", [(0, 5), (1, 5), (5, 5), (5, 9), (10, 3), (37, 12), (100, 2)])
def test_evenly_spaced_picks_spread_distinct_indices(n, k):
    idx = evenly_spaced(n, k)
    assert idx.dtype == np.int64 and len(idx) == min(n, k)
    assert np.all(np.diff(idx) > 0) and (n == 0 or (idx[0] == 0 and idx[-1] == n - 1))
    if 2 <= len(idx) < n:  # gaps differ by at most one index: even spacing
        gaps = np.diff(idx)
        assert gaps.max() - gaps.min() <= 1
