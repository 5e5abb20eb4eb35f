"""Motion-capture file formats: ASF/AMC and BVH readers and writers.

Every reader raises :class:`quatmotion.FormatError` (naming the file and line) on malformed
input; every writer writes a temporary file and renames it over the target.
"""

from __future__ import annotations

from quatmotion.io._text import decode_text
from quatmotion.io.asf_amc import (
    asf_bone_end_positions,
    asf_text,
    find_asf_for_amc,
    parse_amc,
    parse_asf,
    read_amc,
    read_asf,
    write_amc,
    write_asf,
)
from quatmotion.io.bvh import (
    BVH_UNITS,
    PLAUSIBLE_FIGURE_CM,
    bvh_text,
    detect_bvh_scale,
    parse_bvh,
    read_bvh,
    to_bvh_skeleton,
    write_bvh,
)
from quatmotion.io.files import (
    FAR_CM,
    MOTION_SUFFIXES,
    PLAUSIBLE_FPS,
    Doubt,
    find_motion_files,
    implausible_values,
    parse_motion,
    posed_size_cm,
    read_motion,
    write_motion,
)

__all__ = [
    "BVH_UNITS",
    "FAR_CM",
    "Doubt",
    "MOTION_SUFFIXES",
    "PLAUSIBLE_FIGURE_CM",
    "PLAUSIBLE_FPS",
    "asf_bone_end_positions",
    "asf_text",
    "bvh_text",
    "decode_text",
    "detect_bvh_scale",
    "find_asf_for_amc",
    "find_motion_files",
    "implausible_values",
    "parse_amc",
    "posed_size_cm",
    "parse_asf",
    "parse_bvh",
    "parse_motion",
    "read_amc",
    "read_asf",
    "read_bvh",
    "read_motion",
    "to_bvh_skeleton",
    "write_amc",
    "write_asf",
    "write_bvh",
    "write_motion",
]
