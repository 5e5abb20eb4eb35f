"""``quatmotion info | convert | generate``: look at, convert and make single clips."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table
from typer.core import TyperCommand

from quatmotion.cli._app import app
from quatmotion.cli._clip_files import Outputs, clip_files, write_clip
from quatmotion.cli._common import (
    CliInputError,
    ForceOption,
    JointMapOption,
    JsonOption,
    SkeletonOption,
    TakeOption,
    TranslationsOption,
    UnitsOption,
    at_least,
    check_outputs,
    check_translations,
    check_units,
    check_writable,
    console,
    joint_map_entries,
    number_in,
    print_json,
    progress_bar,
    read_clip,
    require_file,
    unit_label,
    unit_text,
    user_errors,
)

if TYPE_CHECKING:
    import click

    from quatmotion.motion import Motion, Skeleton

# A generated clip is built in memory, about 8 kB a frame at its peak: this bound keeps it near
# 2.5 GB (and its BVH near 200 MB).
MAX_GENERATED_FRAMES = 300_000
FPS_RANGE = (1.0, 1000.0)  # frames per second of motion capture


def _cm(value: float) -> str:
    """A length for a table: one decimal, or 3 significant digits when absurdly large; ``-``
    for none (NaN)."""
    if value != value:
        return "-"
    return f"{value:.1f}" if abs(value) < 1e6 else f"{value:.3g}"


def _rest_pose(skeleton: Skeleton) -> tuple[float, str | None]:
    """The rest pose's vertical extent, and the axis it lies along when it is not upright
    (``"?"`` when neither a head nor feet are found to tell).

    Upright means the head straight above the feet (Bandai's rest pose lies along X). Never the
    skeleton's largest extent: a T-pose's arm span equals its height.
    """
    import numpy as np

    from quatmotion.io import find_body

    rest = skeleton.rest_positions()
    extent = np.ptp(rest, axis=0)
    try:
        from quatmotion.pose.skeleton16 import joint_indices16

        joints = rest[joint_indices16(skeleton)]
        body = joints[3] - 0.5 * (joints[12] + joints[15])
    except ValueError:  # not a skeleton the 16 joints map: its named head and feet (the root
        # standing in for the one of them not found)
        parts = find_body(skeleton)
        if parts is None or (parts.head is None and not parts.ankles):
            return float(extent[1]), "?"
        head = rest[0] if parts.head is None else rest[parts.head]
        feet = rest[list(parts.ankles)].mean(axis=0) if parts.ankles else rest[0]
        body = head - feet
    length = float(np.linalg.norm(body))
    if length > 0 and abs(body[1]) < 0.9 * length:
        return float(extent[1]), "XYZ"[int(np.argmax(np.abs(body)))]
    return float(extent[1]), None


def _rest_pose_text(height: float, lying: str | None) -> str:
    if lying == "?":
        return f"{_cm(height)} (vertical extent; no head or feet found to tell the body's axis)"
    return f"- (rest pose not upright: it lies along {lying})" if lying else _cm(height)


def _translations_text(skeleton: Skeleton) -> str | None:
    """How position channels on joints other than the root were read, for BVH skeletons."""
    mode = skeleton.extras.get("bvh_translations")
    if mode is None:
        return None
    joints = sum(any(c[0] == "t" for c in ch) for ch in skeleton.channels[1:])
    how = {
        "absolute": "read as absolute (replacing the offsets)",
        "relative": "read as relative to the offsets",
        "root-only": "ignored (root only)",
    }[mode]
    said = "detected" if skeleton.extras.get("bvh_translations_guessed") else "given"
    return f"on {joints} joints besides the root, {how} ({said})"


def _take_text(skeleton: Skeleton) -> str | None:
    """Which take of an FBX file was read, of which."""
    takes = skeleton.extras.get("fbx_takes")
    if takes is None:
        return None
    if not takes:
        return "none (the file holds no animation)"
    from quatmotion.io.fbx import take_labels

    read = skeleton.extras.get("fbx_take")
    short = dict(zip(takes, take_labels(takes), strict=True))  # what --take and clip names say

    def named(take: str) -> str:
        return repr(take) if short[take] == take else f"{take!r} ({short[take]})"

    others = [named(t) for t in takes if t != read]
    rest = f"; also {', '.join(others)} (--take NAME)" if others else ""
    return f"{named(read)} of {len(takes)}{rest}"


def _stature(skeleton: Skeleton) -> float | None:
    try:
        from quatmotion.pose.skeleton16 import stature16

        return stature16(skeleton)
    except ValueError:  # not a skeleton the 16-joint pose skeleton maps
        return None


def _mapping(skeleton: Skeleton) -> tuple[object | None, str | None]:
    """The humanoid mapping (:func:`quatmotion.pose.skeleton16.humanoid_map`) or why there is
    none."""
    from quatmotion.pose.skeleton16 import humanoid_map

    try:
        return humanoid_map(skeleton), None
    except ValueError as error:
        return None, str(error)


def _mapping_rows(skeleton: Skeleton) -> list[tuple[str, str]]:
    from quatmotion.motion.humanoid import JOINTS_16

    mapping, why = _mapping(skeleton)
    if mapping is None:
        return [("16-joint body", f"not mapped: {why}")]
    rows = [("16-joint body", mapping.summary())]
    for name, point, how in zip(JOINTS_16, mapping.points, mapping.how, strict=True):
        rows.append((f"  {name}", f"{point} ({how})"))
    return rows


def _skeleton_rows(skeleton: Skeleton, asf: str | None = None) -> list[tuple[str, str]]:
    height, lying = _rest_pose(skeleton)
    rows = [
        ("skeleton", skeleton.name or "-"),
        *([("skeleton file", asf)] if asf else []),
        ("joints", str(skeleton.n_joints)),
        ("end sites", str(skeleton.n_sites)),
        ("unit", unit_text(unit_label(skeleton))),
        ("rest pose height (cm)", _rest_pose_text(height, lying)),
    ]
    translations = _translations_text(skeleton)
    if translations:
        rows.append(("position channels", translations))
    take = _take_text(skeleton)
    if take:
        rows.append(("take", take))
    stature = _stature(skeleton)
    if stature is not None:
        rows.append(("ankle-to-head bone chain (cm)", _cm(stature)))
    return rows + _mapping_rows(skeleton)


def _skeleton_doc(skeleton: Skeleton, asf: str | None = None) -> dict[str, object]:
    height, lying = _rest_pose(skeleton)
    doc: dict[str, object] = {
        "skeleton": skeleton.name,
        "joints": skeleton.n_joints,
        "end_sites": skeleton.n_sites,
        **unit_label(skeleton),
        "rest_pose_height_cm": None if lying and lying != "?" else height,
        "rest_pose_lies_along": None if lying == "?" else lying,
        "body_axis_known": lying != "?",
        "ankle_to_head_cm": _stature(skeleton),
    }
    if asf:
        doc["skeleton_file"] = asf
    if "fbx_takes" in skeleton.extras:
        doc["take"] = skeleton.extras["fbx_take"]
        doc["takes"] = list(skeleton.extras["fbx_takes"])
    mapping, why = _mapping(skeleton)
    doc["body16"] = (
        {"family": mapping.family, "joints": mapping.as_dict(), "estimated": mapping.estimated}
        if mapping is not None
        else {"error": why}
    )
    if "bvh_translations" in skeleton.extras:
        doc["position_channels"] = skeleton.extras["bvh_translations"]
        doc["position_channels_detected"] = bool(skeleton.extras["bvh_translations_guessed"])
    return doc


def _frame_count(motion: Motion) -> str:
    n = motion.n_frames
    if n == 0:
        return "0 (no frames)"
    amc = motion.skeleton.extras.get("format") == "asf"
    numbering = f"; numbered 1 to {n} in the AMC file" if amc else ""
    return f"{n} (frames 0 to {n - 1}{numbering})"


def _pelvis(motion: Motion) -> int:
    """The joint that carries the body: the 16-joint Hip where the skeleton maps (Bandai's root
    is a static joint below its moving Hips), else the root."""
    try:
        from quatmotion.pose.skeleton16 import joint_indices16

        return int(joint_indices16(motion.skeleton)[0])
    except ValueError:
        return 0


def _motion_measures(motion: Motion) -> tuple[float, str, list[float]]:
    """Median vertical extent over frames, the pelvis joint and its position at frame 0 (NaN
    for a clip of no frames)."""
    import numpy as np

    from quatmotion.motion import forward_kinematics, standing_height

    if motion.n_frames == 0:
        return float("nan"), motion.skeleton.joint_names[_pelvis(motion)], [float("nan")] * 3
    # Absurd but finite values (reported as warnings) may overflow on the way: show what comes.
    with np.errstate(all="ignore"):
        step = max(1, motion.n_frames // 200)
        extent = standing_height(motion, step)
        pelvis = _pelvis(motion)
        at_start = forward_kinematics(motion.slice(0, 1)).positions[0, pelvis]
    return float(extent), motion.skeleton.joint_names[pelvis], [float(v) for v in at_start]


def _motion_summary(motion: Motion, asf: str | None = None) -> Table:
    table = Table(show_header=False)
    table.add_column("field", style="bold")
    table.add_column("value")
    rows = _skeleton_rows(motion.skeleton, asf)
    rows[3 + bool(asf) : 3 + bool(asf)] = [
        ("frames", _frame_count(motion)),
        ("fps", f"{motion.fps:g}"),
        ("duration (s)", f"{motion.duration:.3f}"),
    ]
    extent, pelvis, at_start = _motion_measures(motion)
    rows.append(("vertical extent, median over frames (cm)", _cm(extent)))
    rows.append((f"{pelvis} at frame 0 (cm)", " ".join(map(_cm, at_start))))
    for field, value in rows:
        table.add_row(field, value)
    return table


def _motion_doc(motion: Motion, asf: str | None = None) -> dict[str, object]:
    extent, pelvis, at_start = _motion_measures(motion)
    return {
        **_skeleton_doc(motion.skeleton, asf),
        "frames": motion.n_frames,
        "fps": motion.fps,
        "duration_s": motion.duration,
        "vertical_extent_cm": extent,
        "pelvis": {"joint": pelvis, "frame0_cm": at_start},
    }


def _title(path: Path) -> None:
    # A line of its own, not a table title: Rich folds a title to the table's width.
    console.print(str(path), markup=False, highlight=False, soft_wrap=True)


def _asf_used(file: Path, skeleton: Path | None) -> tuple[Path | None, str | None]:
    """The ASF an AMC is read with, and how it was found, for ``info`` to say."""
    if file.suffix.lower() != ".amc" or not file.is_file():
        return skeleton, None
    if skeleton is not None:
        return skeleton, f"{skeleton} (given)"
    from quatmotion.io import match_asf_for_amc

    match = match_asf_for_amc(file)
    return match.path, f"{match.path} ({match.rule})"


@app.command()
def info(
    file: Annotated[Path, typer.Argument(help="A .amc, .bvh, .glb/.gltf, .fbx or .asf file.")],
    skeleton: SkeletonOption = None,
    units: UnitsOption = None,
    translations: TranslationsOption = "auto",
    take: TakeOption = None,
    joint_map: JointMapOption = None,
    as_json: JsonOption = False,
) -> None:
    """Print a clip's skeleton, unit, frames, fps, duration, body measures (cm) and which of
    its joints are the 16 of the body search compares (and how each was found)."""
    with user_errors():
        check_units(units)
        if file.suffix.lower() == ".asf":
            from quatmotion.io import read_asf
            from quatmotion.motion import with_joint_map

            sk = read_asf(require_file(file), units)
            entries = joint_map_entries(joint_map)
            if entries:
                from quatmotion.io import joint_map_dict

                sk = with_joint_map(sk, joint_map_dict(entries))
            if as_json:
                print_json({"file": str(file), **_skeleton_doc(sk)})
                return
            _title(file)
            table = Table(show_header=False)
            for field, value in _skeleton_rows(sk):
                table.add_row(field, value)
            console.print(table)
            return
        asf, asf_text = _asf_used(require_file(file), skeleton)
        motion = read_clip(
            file,
            asf,
            units,
            translations=translations,
            take=take,
            joint_map=joint_map_entries(joint_map),
        )
        if as_json:
            print_json({"file": str(file), **_motion_doc(motion, asf_text)})
            return
        _title(file)
        console.print(_motion_summary(motion, asf_text))


@app.command()
def convert(
    paths: Annotated[
        list[Path],
        typer.Argument(
            help="Input clip(s) (.amc, .bvh, .glb/.gltf, .fbx) then the output: a .amc, .bvh, "
            ".glb or .gltf file for one input, else a folder."
        ),
    ],
    skeleton: SkeletonOption = None,
    units: UnitsOption = None,
    translations: TranslationsOption = "auto",
    take: TakeOption = None,
    to: Annotated[str, typer.Option(help="Output format when writing into a folder.")] = "bvh",
    force: ForceOption = False,
) -> None:
    """Convert AMC <-> BVH by extension (ASF+AMC -> BVH too); many inputs into a folder.

    An AMC output gets its ASF beside it, same name. Existing files are kept unless --force;
    an input is never overwritten. If a clip fails, nothing written by the command is left.
    """
    from quatmotion.io import WRITTEN_SUFFIXES

    with user_errors():
        if len(paths) < 2:
            raise CliInputError("convert needs at least one input and an output")
        *inputs, out = paths
        check_units(units)
        check_translations(translations)
        fmt = "." + to.lower().lstrip(".")
        if fmt not in WRITTEN_SUFFIXES:
            written = ", ".join(w.lstrip(".") for w in WRITTEN_SUFFIXES)
            raise CliInputError(f"--to must be one of {written}; got {to!r}")
        for path in inputs:  # fail before writing anything when an input is missing
            require_file(path)
        if take is not None and len(inputs) > 1:
            raise CliInputError("--take names the take of one input; convert several one by one")
        targets, into_folder = _convert_targets(inputs, out, fmt)
        if into_folder:
            check_writable(out, folder=True)
        check_outputs(targets, [*inputs, skeleton], force=force)  # before reading: fail fast
        # Read everything first: a bad clip then stops the command before anything is written.
        motions = _convert_inputs(inputs, skeleton, units, translations, take)
        planned = [clip_files(t, m.skeleton) for m, t in zip(motions, targets, strict=True)]
        check_outputs([f for files in planned for f in files], [*inputs, skeleton], force=force)
        with Outputs() as outputs:
            if into_folder:
                outputs.folder(out)
            for motion, files in zip(motions, planned, strict=True):
                write_clip(motion, files, outputs)
        written = [f for files in planned for f in files]
        if into_folder:
            console.print(f"wrote {len(inputs)} clip(s) to {out}")
        else:
            console.print(f"wrote {', '.join(str(w) for w in written)}")


def _convert_targets(inputs: list[Path], out: Path, fmt: str) -> tuple[list[Path], bool]:
    """``convert``'s output files (``out`` itself, or one per input in the folder ``out``),
    and whether ``out`` is a folder; refused before anything is read or written."""
    from quatmotion.io import MOTION_SUFFIXES, WRITTEN_SUFFIXES

    into_folder = len(inputs) > 1 or out.is_dir()
    if not into_folder and out.suffix.lower() not in WRITTEN_SUFFIXES:
        raise CliInputError(
            f"{out}: unknown output type {out.suffix!r} (expected "
            f"{', '.join(WRITTEN_SUFFIXES)}, or an existing folder)"
        )
    if into_folder and out.exists() and not out.is_dir():
        raise CliInputError(f"{out}: several inputs need an output folder, not a file")
    if into_folder and out.suffix.lower() in MOTION_SUFFIXES and not out.is_dir():
        raise CliInputError(f"{out}: several inputs need an output folder")
    targets = [out] if not into_folder else [out / f"{p.stem}{fmt}" for p in inputs]
    if len(set(targets)) < len(targets):
        raise CliInputError("two inputs have the same name: their outputs would collide")
    return targets, into_folder


def _convert_inputs(
    inputs: list[Path],
    skeleton: Path | None,
    units: str | None,
    translations: str,
    take: str | None,
) -> list[Motion]:
    """Every input read (a bad clip stops ``convert`` before anything is written). In a batch,
    ``--skeleton`` is for its AMC files, ``--units`` and ``--bvh-translations`` for its BVH
    files (as every batch command reads them), ``--take`` for one input only."""
    motions = []
    alone = len(inputs) == 1
    with progress_bar() as progress:
        task = progress.add_task("reading", total=len(inputs))
        for path in inputs:
            bvh = path.suffix.lower() == ".bvh"
            motions.append(
                read_clip(
                    path,
                    skeleton if alone or not bvh else None,
                    units if alone or bvh else None,
                    translations=translations if bvh else "auto",
                    take=take if alone else None,
                )
            )
            progress.advance(task)
    return motions


class _GenerateCommand(TyperCommand):
    """``generate``'s help lists the motion kinds, read from the generator when help is shown
    (importing it when the command line starts would slow every command down)."""

    def format_help(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        from quatmotion.synthetic import KINDS

        self.help = f"Write one procedural clip. KIND is one of: {', '.join(KINDS)}."
        super().format_help(ctx, formatter)


@app.command(cls=_GenerateCommand)
def generate(
    kind: Annotated[str, typer.Argument(help="Motion kind (listed above).")],
    out: Annotated[Path, typer.Argument(help="Output .bvh or .amc (ASF written beside).")],
    seed: Annotated[int, typer.Option(help="Seed of style and noise (0 or more).")] = 0,
    frames: Annotated[
        int | None,
        typer.Option(help=f"Frames, 1 to {MAX_GENERATED_FRAMES} (default: kind-dependent)."),
    ] = None,
    fps: Annotated[
        float, typer.Option(help=f"Frame rate, {FPS_RANGE[0]:g} to {FPS_RANGE[1]:g}.")
    ] = 120.0,
    force: ForceOption = False,
) -> None:
    """Write one procedural clip (walk, run, jump, jumping_jack, squat, ...)."""
    with user_errors():
        at_least("--seed", seed, 0)
        if frames is not None:
            at_least("--frames", frames, 1, MAX_GENERATED_FRAMES)
        number_in("--fps", fps, *FPS_RANGE)
        from quatmotion.synthetic import KINDS, cmu_skeleton, generate_clip

        if kind not in KINDS:
            raise CliInputError(f"unknown motion kind {kind!r}; choose from {', '.join(KINDS)}")
        skeleton = cmu_skeleton()
        targets = clip_files(out, skeleton)
        check_outputs(targets, force=force)  # before the work, which may take a while
        motion = generate_clip(kind, seed, n_frames=frames, fps=fps, skeleton=skeleton)
        with Outputs() as outputs:
            write_clip(motion, targets, outputs)
        console.print(
            f"wrote {', '.join(str(w) for w in targets)} "
            f"({motion.n_frames} frames at {motion.fps:g} fps)"
        )
