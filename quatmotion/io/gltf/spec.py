"""What the glTF 2.0 specification fixes that both the reader and the writer use: the file
suffixes, the metre, the accessors' component types and sizes, the GLB chunk tags, and the
quaternion order of the file (``x y z w``) against quatmotion's (``w x y z``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

GLTF_SUFFIXES = (".glb", ".gltf")
CM_PER_METRE = 100.0
FLOAT = 5126  # componentType of float32
COMPONENTS = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}
DTYPES = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32}
DTYPES[FLOAT] = np.float32
NORMALIZED_MAX = {5120: 127.0, 5121: 255.0, 5122: 32767.0, 5123: 65535.0}

GLB_JSON = 0x4E4F534A  # a .glb's chunk types
GLB_BIN = 0x004E4942


def xyzw(q: NDArray[np.float64]) -> NDArray[np.float64]:
    """Quaternions ``(..., 4)`` from ``w x y z`` (here) to ``x y z w`` (the file)."""
    return np.concatenate((q[..., 1:], q[..., :1]), axis=-1)


def wxyz(q: NDArray[np.float64]) -> NDArray[np.float64]:
    """Quaternions ``(..., 4)`` from ``x y z w`` (the file) to ``w x y z`` (here)."""
    return np.concatenate((q[..., 3:], q[..., :3]), axis=-1)
