"""The array type aliases every package uses: defined once, here (the bottom of the dependency chain)."""

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

__all__ = ["FloatArray", "ImageArray", "IndexArray", "MaskArray"]
