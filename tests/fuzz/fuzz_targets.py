"""One fuzz target per reader: the bytes of a file in, a Motion (or Skeleton) or a FormatError
out. Anything else (another exception, a result with values that are not finite, a clip over
the limits, a message that does not name the file) is a finding: the target raises
:class:`FindingError` with the original exception chained."""

from __future__ import annotations

import warnings

import fuzz_files
import numpy as np
from fuzz_corpus import OWN, amc_skeleton

from quatmotion import io, limits
from quatmotion.errors import FormatError
from quatmotion.motion import Motion, Skeleton

NAMES = {
    "bvh": "fuzz.bvh",
    "asf": "fuzz.asf",
    "amc": "fuzz.amc",
    "gltf": "fuzz.gltf",
    "glb": "fuzz.glb",
    "fbx": "fuzz.fbx",
}


class FindingError(AssertionError):
    """A reader did something other than read the file or refuse it with a FormatError."""


def _read(reader: str, data: bytes) -> Motion | Skeleton:
    name = NAMES[reader]
    if reader == "asf":
        return io.parse_asf(io.decode_text(data, name), name)
    if reader == "amc":
        return io.parse_motion(data, name, skeleton=amc_skeleton())
    return io.parse_motion(data, name)  # an upload: no file is opened


def run(reader: str, data: bytes) -> str:
    """Read ``data`` as ``reader``'s file: ``"read"`` or ``"refused"``, or raise FindingError."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # what a reader tolerated is no finding
            if reader in OWN:
                fuzz_files.read(reader, data)
                return "read"
            result = _read(reader, data)
    except FormatError as error:
        if not _names_the_file(reader, str(error)):
            raise FindingError(f"{reader}: a FormatError that names no file: {error}") from error
        return "refused"
    except Exception as error:  # noqa: BLE001 (anything else is what the fuzzer looks for)
        raise FindingError(f"{reader}: {type(error).__name__}: {error}") from error
    _check(reader, result)
    return "read"


def _names_the_file(reader: str, message: str) -> bool:
    if reader in OWN:  # read from bytes, or from a temporary file of fuzz_files
        return message.startswith("<bytes>") or "quatmotion-fuzz-" in message.split(":", 1)[0]
    return message.startswith(NAMES[reader])


def _check(reader: str, result: Motion | Skeleton) -> None:
    skeleton = result if isinstance(result, Skeleton) else result.skeleton
    bound = limits.current()
    if skeleton.n_joints > bound.joints:
        raise FindingError(f"{reader}: {skeleton.n_joints} joints read, over the limit")
    if not np.isfinite(skeleton.offsets).all():
        raise FindingError(f"{reader}: offsets that are not finite")
    if isinstance(result, Motion):
        if result.n_frames > bound.frames or not 0 < result.fps <= bound.fps:
            raise FindingError(f"{reader}: {result.n_frames} frames at {result.fps} read")
        arrays = [result.rotations, result.root_translation]
        if result.joint_translations is not None:
            arrays.append(result.joint_translations)
        if not all(np.isfinite(a).all() for a in arrays):
            raise FindingError(f"{reader}: a motion with values that are not finite")
