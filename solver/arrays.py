"""Array type aliases and even thinning, which every package uses: defined once, here (the bottom).

This module sits at the bottom of the dependency chain.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

#: Real-valued arrays: poses, points, pixels, angles (float64).
FloatArray = NDArray[np.float64]
#: 8-bit images, (H, W, 3) RGB or (H, W) grey.
ImageArray = NDArray[np.uint8]
#: Boolean masks, e.g. (H, W) pixels or (P,) points.
MaskArray = NDArray[np.bool_]
#: Integer index arrays (body ids, geom ids).
IndexArray = NDArray[np.int64]



def evenly_spaced(n: int, k: int) -> IndexArray:
    """(m,) int64, sorted and distinct: at most ``k`` indices into ``range(n)``, evenly spread, first and last included.

    ``k >= n`` gives every index; ``n == 0`` none.
    """
    return np.unique(np.linspace(0, n - 1, min(n, k)).round().astype(np.int64))


__all__ = ["FloatArray", "ImageArray", "IndexArray", "MaskArray", "evenly_spaced"]
