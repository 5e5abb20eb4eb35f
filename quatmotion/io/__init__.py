"""Motion-capture file formats: ASF/AMC, BVH and glTF readers and writers, FBX in.

Every reader raises :class:`quatmotion.FormatError` (naming the file and line) on malformed
input; every writer writes a temporary file and renames it over the target.
"""

from __future__ import annotations

from quatmotion.io._text import decode_text
from quatmotion.io.asf_amc import (
    AsfMatch,
    asf_bone_end_positions,
    asf_extras,
    asf_text,
    find_asf_for_amc,
    match_asf_for_amc,
    parse_amc,
    parse_asf,
    read_amc,
    read_asf,
    write_amc,
    write_asf,
)
from quatmotion.io.bvh import (
    BVH_UNITS,
    TRANSLATION_MODES,
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
    WRITTEN_SUFFIXES,
    Doubt,
    feet_below_floor,
    find_motion_files,
    implausible_values,
    parse_motion,
    posed_size_cm,
    read_motion,
    read_motion_checked,
    unit_reading,
    write_motion,
)
from quatmotion.io.joint_map import joint_map_dict, joint_map_pairs, read_joint_map
from quatmotion.io.units import (
    LENGTH_UNITS,
    PLAUSIBLE_FIGURE_CM,
    body_size,
    find_body,
    length_unit,
)

__all__ = [
    "AsfMatch",
    "BVH_UNITS",
    "FAR_CM",
    "Doubt",
    "LENGTH_UNITS",
    "MOTION_SUFFIXES",
    "PLAUSIBLE_FIGURE_CM",
    "PLAUSIBLE_FPS",
    "TRANSLATION_MODES",
    "WRITTEN_SUFFIXES",
    "asf_bone_end_positions",
    "asf_extras",
    "asf_text",
    "body_size",
    "bvh_text",
    "decode_text",
    "detect_bvh_scale",
    "find_asf_for_amc",
    "find_body",
    "find_motion_files",
    "feet_below_floor",
    "implausible_values",
    "length_unit",
    "match_asf_for_amc",
    "parse_amc",
    "posed_size_cm",
    "parse_asf",
    "parse_bvh",
    "parse_motion",
    "read_amc",
    "read_asf",
    "read_bvh",
    "read_motion",
    "read_motion_checked",
    "to_bvh_skeleton",
    "unit_reading",
    "write_amc",
    "write_asf",
    "write_bvh",
    "write_motion",
    "joint_map_dict",
    "joint_map_pairs",
    "read_joint_map",
]
