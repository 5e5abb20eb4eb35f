"""Write large valid uploads of every kind the web app parses, for
``tools/measure-upload-memory.py``: one CMU take (02_01: ASF/AMC, 31 joints) repeated to
FRAMES frames, as ``big.bvh``, ``big.amc`` with ``big.asf``, ``big.glb``, ``big.gltf``; and
``big.fbx`` exported by Blender's FBX exporter (when ``blender`` is on PATH) from the CMU
BVH of another take (07_01) repeated to FRAMES / 5 frames (Blender's BVH importer wants channels
on every joint, which the BVH written from an ASF skeleton does not have).

    python tools/make-upload-samples.py OUT_DIR [FRAMES]

Reads the shared data (``$QUATMOTION_DATA``, default ``../shared/data``); FRAMES defaults to
20,000.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

from quatmotion.io import read_motion, write_asf, write_motion

_BLENDER = """
import bpy, sys
import io_anim_bvh.import_bvh
source, target, frames = sys.argv[sys.argv.index("--") + 1 :]
# Blender 3.4's BVH importer opens its file in mode "rU", which Python 3.11 refuses
# (tools/make_fbx_fixtures.py says more): the same open without the "U".
io_anim_bvh.import_bvh.open = lambda f, mode="r", *a, **k: open(f, mode.replace("U", ""), *a, **k)
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_anim.bvh(filepath=source, global_scale=0.01, frame_start=1,
                        use_fps_scale=False, update_scene_fps=True, update_scene_duration=True)
bpy.context.scene.frame_start = 1
bpy.context.scene.frame_end = int(frames)
bpy.ops.export_scene.fbx(filepath=target, object_types={"ARMATURE"}, add_leaf_bones=False,
                         bake_anim=True, bake_anim_use_all_bones=True,
                         bake_anim_use_nla_strips=False, bake_anim_use_all_actions=False,
                         bake_anim_force_startend_keying=True, bake_anim_step=1.0,
                         bake_anim_simplify_factor=0.0)
"""


def _repeat_bvh(source: Path, frames: int, out: Path) -> None:
    lines = source.read_text(encoding="latin-1").splitlines()
    time_line = next(i for i, line in enumerate(lines) if "Frame Time" in line)
    data = lines[time_line + 1 :]
    data = (data * -(-frames // len(data)))[:frames]
    head = [line for line in lines[:time_line] if not line.strip().startswith("Frames:")]
    out.write_text("\n".join([*head, f"Frames: {frames}", lines[time_line], *data]) + "\n")


def main() -> None:
    out = Path(sys.argv[1])
    frames = int(sys.argv[2]) if len(sys.argv) > 2 else 20_000
    data = Path(os.environ.get("QUATMOTION_DATA", Path.cwd().parent / "shared" / "data"))
    take = read_motion(data / "cmu" / "02" / "02_01.amc", skeleton=data / "cmu" / "02" / "02.asf")
    repeats = -(-frames // take.n_frames)
    fields = {"rotations": np.tile(take.rotations, (repeats, 1, 1))[:frames]}
    fields["root_translation"] = np.tile(take.root_translation, (repeats, 1))[:frames]
    big = dataclasses.replace(take, **fields)
    out.mkdir(parents=True, exist_ok=True)
    write_asf(big.skeleton, out / "big.asf")
    for suffix in (".amc", ".bvh", ".glb", ".gltf"):
        write_motion(big, out / f"big{suffix}")
    if shutil.which("blender"):
        script = out / "export_fbx.py"
        script.write_text(_BLENDER)
        command = ["blender", "-b", "--factory-startup", "--python", str(script), "--"]
        source = out / "for_fbx.bvh"
        fbx_frames = max(1, frames // 5)  # Blender bakes every frame: minutes for thousands
        _repeat_bvh(data / "cmu_bvh" / "07" / "07_01.bvh", fbx_frames, source)
        subprocess.run([*command, str(source), str(out / "big.fbx"), str(fbx_frames)], check=True)
        script.unlink()
        source.unlink()
    for path in sorted(out.iterdir()):
        print(f"{path.name}: {path.stat().st_size / 1e6:.1f} MB")


if __name__ == "__main__":
    main()
