"""Acclaim ASF (skeleton) and AMC (motion) files: readers and writers, a module per job
(:mod:`~quatmotion.io.asf_amc.asf`: reading skeletons; :mod:`~quatmotion.io.asf_amc.amc`:
reading motions; :mod:`~quatmotion.io.asf_amc.write`: writing both).

Conventions
-----------
* Lengths: ``:units length L`` means one file unit is ``1/L`` inch, so centimetres are
  ``value * 2.54 / L`` (CMU and HDM05 use ``L = 0.45``: one unit is about 5.644 cm). Missing
  ``length`` means ``L = 1`` (inches). ``mass`` is kept for the writer, not used. A unit
  outside :data:`quatmotion.io.units.LENGTH_UNIT_RANGE_CM` (``length 1e-300``) is refused.
* Bounds: the bones are counted before any line is split and parsed in linear time; bones,
  frames, frames x joints and the frame rate given are checked against
  :func:`quatmotion.limits.current` (a ``FormatError`` naming the file and line).
* Angles: ``:units angle deg|rad`` for the ASF; an AMC's ``:DEGREES`` / ``:RADIANS`` header
  decides for the AMC (the ASF's unit when neither is present). Radians inside.
* Euler angles (``axis``, ``orientation``, dof values) are extrinsic in the order listed: for
  ``axis a b c XYZ`` and ``dof rx ry rz`` the rotation is ``R = Rz @ Ry @ Rx``.
* Skeleton mapping: joint 0 is the root; every ASF bone becomes the joint at the bone's START.
  A joint's offset from its parent joint is the parent bone's ``direction * length`` (zero for
  the root's children), in centimetres; each leaf bone carries an end site at its own
  ``direction * length``. Rotation channels are the bone's dofs in file order, ``euler =
  "extrinsic"``, ``axes`` the bone's ``axis`` ``C``. The stored local rotation is ``C M C^-1``
  (``M`` the dof rotation), so a bone's global rotation is ``parent_global @ C @ M @ C^-1``.
* The root: ``order`` gives its channels; ``orientation`` (composed in the order of ``axis``)
  is its ``C``; ``position`` is its rest position (``offsets[0]``) and the AMC translation is
  added to it: ``root_translation = position + (TX, TY, TZ)``, in centimetres.
* Joints are listed root first, then the bones in ASF file order when that order already puts
  parents first (CMU, HDM05), otherwise in depth-first hierarchy order.
* ``dof l`` (bone length change) is read and ignored; :func:`write_amc` writes 0 for it. Bone
  translation dofs (``tx ty tz`` on a non-root bone) are not supported (FormatError).
* ``Skeleton.extras`` keeps what :func:`write_asf` needs: ``format="asf"``, ``asf_units``,
  ``asf_version``, ``asf_name``, ``asf_documentation``, ``asf_root`` and ``asf_bones`` (file
  order, each with id, name, direction, length, axis, dof, limits and other raw lines),
  ``asf_hierarchy``, ``length_scale`` (cm per unit), ``angle_unit``.
* The AMC frame rate is not in the file: ``fps`` defaults to 120 (CMU, HDM05).
"""

from quatmotion.io.asf_amc.amc import (
    AsfMatch,
    find_asf_for_amc,
    match_asf_for_amc,
    parse_amc,
    read_amc,
)
from quatmotion.io.asf_amc.asf import asf_bone_end_positions, asf_extras, parse_asf, read_asf
from quatmotion.io.asf_amc.write import amc_channel_values, asf_text, write_amc, write_asf

__all__ = [
    "AsfMatch",
    "amc_channel_values",
    "asf_bone_end_positions",
    "asf_extras",
    "asf_text",
    "find_asf_for_amc",
    "match_asf_for_amc",
    "parse_amc",
    "parse_asf",
    "read_amc",
    "read_asf",
    "write_amc",
    "write_asf",
]
