"""Make the FBX test files in tests/data/fbx with a real exporter: Blender's.

Run by hand (CI never runs it; the files it writes are committed), from the project root:

    blender -b --factory-startup --python tools/make_fbx_fixtures.py -- [DATA_DIR]

DATA_DIR is the shared mocap folder (default ``$QUATMOTION_DATA`` or ``../shared/data``).
Blender 3.4 (Debian's ``apt-get install blender``) imports a short excerpt of a shared CMU
BVH and a shared Bandai-Namco BVH with its BVH importer and exports each with its FBX
exporter, the way a user would hand us a file:

* ``*_bvh_names.fbx``: the BVH's joint names; the CMU file holds two takes (two excerpts of
  one trial, each an action), the Bandai file one;
* ``*_mixamo.fbx``: renamed to Mixamo's conventions (``mixamorig:`` namespace), with
  Blender's leaf bones (``*_end``) as Mixamo files have them;
* ``*_unreal.fbx``: renamed to Unreal's mannequin conventions (``pelvis``, ``thigh_l``...),
  exported Z up as Unreal's own files are.

The excerpt BVHs are imported at the scale that makes Blender's metres right (CMU's unit is
1/0.45 inch, Bandai's the centimetre), so each FBX holds a figure of human size. What was
made is written to ``tests/data/fbx/fixtures.json`` (source file, first frame, frames, scale,
renaming, takes) for the tests that compare the FBX read back with the original BVH.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path

import bpy  # noqa: F401 (Blender's own Python)

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "tests" / "data" / "fbx"

CMU_UNIT_M = 0.0254 / 0.45  # one CMU length unit: 1/0.45 inch
BANDAI_UNIT_M = 0.01

MIXAMO_CMU = {
    "Hips": "Hips", "LHipJoint": "LeftHipJoint", "LeftUpLeg": "LeftUpLeg",
    "LeftLeg": "LeftLeg", "LeftFoot": "LeftFoot", "LeftToeBase": "LeftToeBase",
    "RHipJoint": "RightHipJoint", "RightUpLeg": "RightUpLeg", "RightLeg": "RightLeg",
    "RightFoot": "RightFoot", "RightToeBase": "RightToeBase", "LowerBack": "Spine",
    "Spine": "Spine1", "Spine1": "Spine2", "Neck": "Neck", "Neck1": "Neck1", "Head": "Head",
    "LeftShoulder": "LeftShoulder", "LeftArm": "LeftArm", "LeftForeArm": "LeftForeArm",
    "LeftHand": "LeftHand", "LeftFingerBase": "LeftHandIndex1",
    "LeftHandIndex1": "LeftHandIndex2", "LThumb": "LeftHandThumb1",
    "RightShoulder": "RightShoulder", "RightArm": "RightArm", "RightForeArm": "RightForeArm",
    "RightHand": "RightHand", "RightFingerBase": "RightHandIndex1",
    "RightHandIndex1": "RightHandIndex2", "RThumb": "RightHandThumb1",
}  # fmt: skip
UNREAL_CMU = {
    "Hips": "pelvis", "LHipJoint": "hip_l", "LeftUpLeg": "thigh_l", "LeftLeg": "calf_l",
    "LeftFoot": "foot_l", "LeftToeBase": "ball_l", "RHipJoint": "hip_r",
    "RightUpLeg": "thigh_r", "RightLeg": "calf_r", "RightFoot": "foot_r",
    "RightToeBase": "ball_r", "LowerBack": "spine_01", "Spine": "spine_02",
    "Spine1": "spine_03", "Neck": "neck_01", "Neck1": "neck_02", "Head": "head",
    "LeftShoulder": "clavicle_l", "LeftArm": "upperarm_l", "LeftForeArm": "lowerarm_l",
    "LeftHand": "hand_l", "LeftFingerBase": "index_01_l", "LeftHandIndex1": "index_02_l",
    "LThumb": "thumb_01_l", "RightShoulder": "clavicle_r", "RightArm": "upperarm_r",
    "RightForeArm": "lowerarm_r", "RightHand": "hand_r", "RightFingerBase": "index_01_r",
    "RightHandIndex1": "index_02_r", "RThumb": "thumb_01_r",
}  # fmt: skip
MIXAMO_BANDAI = {
    "joint_Root": "Root", "Hips": "Hips", "Spine": "Spine", "Chest": "Spine1",
    "Neck": "Neck", "Head": "Head", "Shoulder_L": "LeftShoulder", "UpperArm_L": "LeftArm",
    "LowerArm_L": "LeftForeArm", "Hand_L": "LeftHand", "Shoulder_R": "RightShoulder",
    "UpperArm_R": "RightArm", "LowerArm_R": "RightForeArm", "Hand_R": "RightHand",
    "UpperLeg_L": "LeftUpLeg", "LowerLeg_L": "LeftLeg", "Foot_L": "LeftFoot",
    "Toes_L": "LeftToeBase", "UpperLeg_R": "RightUpLeg", "LowerLeg_R": "RightLeg",
    "Foot_R": "RightFoot", "Toes_R": "RightToeBase",
}  # fmt: skip
UNREAL_BANDAI = {
    "joint_Root": "root", "Hips": "pelvis", "Spine": "spine_01", "Chest": "spine_02",
    "Neck": "neck_01", "Head": "head", "Shoulder_L": "clavicle_l", "UpperArm_L": "upperarm_l",
    "LowerArm_L": "lowerarm_l", "Hand_L": "hand_l", "Shoulder_R": "clavicle_r",
    "UpperArm_R": "upperarm_r", "LowerArm_R": "lowerarm_r", "Hand_R": "hand_r",
    "UpperLeg_L": "thigh_l", "LowerLeg_L": "calf_l", "Foot_L": "foot_l", "Toes_L": "ball_l",
    "UpperLeg_R": "thigh_r", "LowerLeg_R": "calf_r", "Foot_R": "foot_r", "Toes_R": "ball_r",
}  # fmt: skip

SOURCES = {
    "cmu": {
        "bvh": "cmu_bvh/07/07_01.bvh",
        "takes": {"walk_a": 60, "walk_b": 180},  # take name: first frame
        "frames": 40,
        "unit_m": CMU_UNIT_M,
        "renames": {"mixamo": MIXAMO_CMU, "unreal": UNREAL_CMU},
    },
    "bandai": {
        "bvh": "bandai1/clips/dataset-1_walk_normal_001.bvh",
        "takes": {"walk": 30},
        "frames": 30,
        "unit_m": BANDAI_UNIT_M,
        "renames": {"mixamo": MIXAMO_BANDAI, "unreal": UNREAL_BANDAI},
    },
}


def excerpt(source: Path, start: int, frames: int, out: Path) -> None:
    """A BVH of ``frames`` frames of ``source`` from frame ``start`` (0-based)."""
    lines = source.read_text(encoding="latin-1").splitlines()
    motion = next(i for i, line in enumerate(lines) if line.strip().upper() == "MOTION")
    time_line = next(i for i in range(motion, len(lines)) if "Frame Time" in lines[i])
    data = lines[time_line + 1 :][start : start + frames]
    assert len(data) == frames, f"{source} has fewer than {start + frames} frames"
    text = lines[: motion + 1] + [f"Frames: {frames}", lines[time_line], *data]
    out.write_text("\n".join(text) + "\n", encoding="latin-1")


def clear() -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)


def _open_without_universal_newlines(file, mode="r", *args, **kwargs):
    return open(file, mode.replace("U", ""), *args, **kwargs)


def import_take(path: Path, unit_m: float):
    # Blender 3.4's BVH importer opens its file in mode "rU", which Python 3.11 refuses (as
    # Debian's Blender runs it): the same open without the "U" (universal newlines are the
    # default in Python 3).
    import io_anim_bvh.import_bvh

    io_anim_bvh.import_bvh.open = _open_without_universal_newlines
    bpy.ops.import_anim.bvh(
        filepath=str(path),
        global_scale=unit_m,
        frame_start=1,
        use_fps_scale=False,
        update_scene_fps=True,
        update_scene_duration=True,
        rotate_mode="NATIVE",
        axis_forward="-Z",
        axis_up="Y",
    )
    return bpy.context.view_layer.objects.active


def build(spec: dict, data: Path, tmp: Path, rename: dict[str, str] | None, prefix: str):
    """The armature with one action per take (named as the take), renamed."""
    clear()
    armature = None
    for take, start in spec["takes"].items():
        bvh = tmp / f"{take}.bvh"
        excerpt(data / spec["bvh"], start, spec["frames"], bvh)
        obj = import_take(bvh, spec["unit_m"])
        action = obj.animation_data.action
        action.name = take
        action.use_fake_user = True
        if armature is None:
            armature = obj
            armature.name = "Armature"
        else:  # the same bones: keep the action, drop the second armature
            obj.animation_data.action = None
            bpy.data.objects.remove(obj, do_unlink=True)
    armature.animation_data.action = bpy.data.actions[next(iter(spec["takes"]))]
    if rename:
        for bone in armature.data.bones:  # Blender renames the actions' channels too
            bone.name = prefix + rename[bone.name]
    bpy.context.scene.frame_start = 1
    bpy.context.scene.frame_end = spec["frames"]
    return armature


def export(path: Path, *, up: str, forward: str, leaf_bones: bool, all_actions: bool) -> None:
    bpy.ops.export_scene.fbx(
        filepath=str(path),
        object_types={"ARMATURE"},
        add_leaf_bones=leaf_bones,
        bake_anim=True,
        bake_anim_use_all_bones=True,
        bake_anim_use_nla_strips=False,
        bake_anim_use_all_actions=all_actions,
        bake_anim_force_startend_keying=True,
        bake_anim_step=1.0,
        bake_anim_simplify_factor=0.0,  # every frame's key: the test compares every frame
        axis_forward=forward,
        axis_up=up,
        apply_unit_scale=True,
        apply_scale_options="FBX_SCALE_NONE",
    )


def main() -> None:
    args = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
    default = os.environ.get("QUATMOTION_DATA") or str(ROOT.parent / "shared" / "data")
    data = Path(args[0] if args else default)
    OUT.mkdir(parents=True, exist_ok=True)
    made = {}
    with tempfile.TemporaryDirectory() as tmp:
        for source, spec in SOURCES.items():
            variants = {
                "bvh_names": (None, "", "Y", "-Z", False),
                "mixamo": (spec["renames"]["mixamo"], "mixamorig:", "Y", "-Z", True),
                "unreal": (spec["renames"]["unreal"], "", "Z", "-Y", False),
            }
            for variant, (rename, prefix, up, forward, leaves) in variants.items():
                name = f"{source}_{variant}.fbx"
                build(spec, data, Path(tmp), rename, prefix)
                several = variant == "bvh_names" and len(spec["takes"]) > 1
                export(OUT / name, up=up, forward=forward, leaf_bones=leaves, all_actions=several)
                takes = spec["takes"] if several else dict(list(spec["takes"].items())[:1])
                made[name] = {
                    "bvh": spec["bvh"],
                    "takes": takes,
                    "frames": spec["frames"],
                    "cm_per_bvh_unit": spec["unit_m"] * 100.0,
                    "names": {k: prefix + v for k, v in rename.items()} if rename else None,
                    "up": up,
                    "leaf_bones": leaves,
                }
    (OUT / "fixtures.json").write_text(json.dumps(made, indent=1, sort_keys=True) + "\n")
    print(f"wrote {len(made)} FBX files to {OUT}")


main()
