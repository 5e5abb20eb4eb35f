"""glTF 2.0 (``.glb`` and ``.gltf``): the skeleton as a node hierarchy with a skin, its motion as
an animation.

A module per job: :mod:`~quatmotion.io.gltf.write` (the writer),
:mod:`~quatmotion.io.gltf.document` (the document's fields, buffers and accessors, checked),
:mod:`~quatmotion.io.gltf.read` (the skeleton and animation read from them), over
:mod:`~quatmotion.io.gltf.spec` (what the specification fixes).

glTF is the open interchange format Blender, three.js, Unity, Unreal and Godot read. The JSON
structure is built with ``pygltflib`` (its dataclasses spell every field of the specification)
and read as plain JSON, each field checked where it is used (pygltflib's parser checks no
type and takes a millisecond a node); the binary data (times, rotations, translations) are
NumPy arrays written and read as raw little-endian float32, which is all the specification
asks of them.

Conventions
-----------
* Lengths are metres in the file (the specification's unit), centimetres in the motion. Y up,
  right-handed, as quatmotion. Quaternions are ``x y z w`` in the file, ``w x y z`` here.
* Writing: one node per joint (named as the joint, its ``translation`` the rest offset),
  joint 0 the scene's root; one child node per end site; a skin whose joints are the joint
  nodes, with inverse bind matrices of the rest pose; one animation (named as the clip) with
  one sampler per joint for its rotation and one for its translation where it moves (the root,
  and every joint of a clip with ``joint_translations``), keyframes at the clip's frame times
  (``k / fps``), linear. The frame rate is kept exactly in the animation's ``extras``. A
  ``.glb`` holds the data in its binary chunk; a ``.gltf`` holds them as a base64 data URI, so
  that it is one file too.
* Reading: the first skin's joints (or, without a skin, the node tree of the first scene)
  are the joints, parents first; their child nodes that are no joint, hold no mesh and have no
  children are end sites. The root's ancestors' transform (an ``Armature`` node's turn or
  uniform scale) is applied to the root. The first animation, or the one named, is sampled at
  its frame rate (``extras`` if there, else the median step of its keyframe times): linear
  and step samplers by interpolation, cubic splines at their keyframes' values. A joint with
  no channel keeps its node's rest rotation and translation in every frame.
* Reading trusts nothing in the file: the JSON is read as plain data (its depth checked
  before parsing), every field is checked for its type and range where it is used, and every
  count, frame rate, duration and buffer length against :func:`quatmotion.limits.current`
  before anything is allocated; a failure is a ``FormatError`` naming the field. A buffer in
  another file is read only for a file on disk, only inside its folder (symbolic links
  followed), only a regular file and no further than its ``byteLength``; a glTF given as bytes
  (an upload) reads no other file.
* The skeleton's ``extras``: ``format="gltf"``, ``length_scale`` (cm per file unit: 100 times
  the ancestors' scale), ``gltf_animation`` (the name read).
"""

from quatmotion.io.gltf.read import parse_gltf, read_gltf
from quatmotion.io.gltf.spec import GLTF_SUFFIXES
from quatmotion.io.gltf.write import gltf_bytes, write_gltf

__all__ = ["GLTF_SUFFIXES", "gltf_bytes", "parse_gltf", "read_gltf", "write_gltf"]
