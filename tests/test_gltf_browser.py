"""A .glb written by quatmotion, opened by the vendored three.js GLTFLoader in headless Chromium
(issue 21): the skeleton's joint positions at frame k, played by three.js's AnimationMixer,
are quatmotion's forward kinematics at frame k within 0.1 cm."""

from __future__ import annotations

import base64

import numpy as np
import pytest

from quatmotion import io
from quatmotion.io.gltf import gltf_bytes
from quatmotion.motion import forward_kinematics
from quatmotion.synthetic import cmu_skeleton, generate_clip
from quatmotion.viz import viewer

THREE_CM = 0.1

# Loads the file from base64 (a page of its own: no server, no file access), plays its first
# animation at each asked frame and reports every node's world position, in node order.
PAGE = """<!doctype html><html><head><meta charset="utf-8"></head><body>
<script>{three}</script>
<script>{loader}</script>
<script>
window.positionsAt = async function (b64, frames, fps) {{
  const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
  const loader = new THREE_GLTF.GLTFLoader();
  const gltf = await new Promise((done, fail) => loader.parse(bytes.buffer, "", done, fail));
  const nodes = await gltf.parser.getDependencies("node");
  const mixer = new THREE.AnimationMixer(gltf.scene);
  mixer.clipAction(gltf.animations[0]).play();
  const v = new THREE.Vector3();
  const out = [];
  for (const k of frames) {{
    mixer.setTime(k / fps);
    gltf.scene.updateMatrixWorld(true);
    out.push(nodes.map((node) => node.getWorldPosition(v).toArray()));
  }}
  return {{
    frames: out,
    names: nodes.map((node) => node.name),
    bones: nodes.filter((node) => node.isBone).length,
    clip: gltf.animations[0].name,
  }};
}};
</script></body></html>"""


def _page() -> str:
    loader = (viewer.static_folder() / "GLTFLoader.min.js").read_text(encoding="utf-8")
    return PAGE.format(three=viewer.asset("three.min.js"), loader=loader)


@pytest.mark.parametrize(
    "source",
    ["asf", "bvh"],
)
def test_three_js_plays_the_glb_where_quatmotion_puts_the_joints(browser, tmp_path, source):
    clip = generate_clip("jumping_jack", 3, n_frames=90, skeleton=cmu_skeleton(160.0))
    if source == "bvh":  # a BVH skeleton (intrinsic channels, no pre-rotations) as read back
        io.write_bvh(clip, tmp_path / "clip.bvh")
        clip = io.read_bvh(tmp_path / "clip.bvh")
    data = base64.b64encode(gltf_bytes(clip)).decode("ascii")
    frames = [0, 17, 45, 89]
    page = browser.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    try:
        page.set_content(_page())
        shown = page.evaluate(
            "([b, f, r]) => window.positionsAt(b, f, r)", [data, frames, clip.fps]
        )
    finally:
        page.close()
    assert not errors, errors
    sk = clip.skeleton
    assert shown["bones"] == sk.n_joints and shown["clip"] == clip.name
    assert len(shown["names"]) == sk.n_joints + sk.n_sites
    expected = forward_kinematics(clip).all_positions()[frames]
    in_cm = np.asarray(shown["frames"]) * 100.0
    error = np.linalg.norm(in_cm - expected, axis=-1)
    assert error.max() <= THREE_CM, (
        f"max {error.max():.4f} cm at {np.unravel_index(error.argmax(), error.shape)}"
    )
    # The figure moves between the frames asked: the comparison is not of one still pose.
    assert np.linalg.norm(expected[1] - expected[0], axis=-1).max() > 5.0
