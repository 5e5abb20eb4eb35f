"""The writer: clips in, a ``.qmz`` library out, as named steps, one module each.

:func:`~quatmotion.codec.writer.build.build_library` (:meth:`quatmotion.codec.Archive.build`)
reads as the steps it takes, none of which holds every clip in the caller's memory:

1. :mod:`~quatmotion.codec.writer.scan`: scan the clips in the workers (:func:`scan_clip`:
   reference, layout key, length, skeleton; every clip named by
   :func:`quatmotion.collection.unique_names`) and admit those that can be stored;
2. :mod:`~quatmotion.codec.writer.skeleton_table`: store their skeletons;
3. :mod:`~quatmotion.codec.writer.plan`: plan the layouts and read a seeded sample of at most
   ``fit_sample`` clips of each to fit them;
4. :mod:`~quatmotion.codec.writer.fit`: learn the shared models (:class:`SharedModels`) on
   the sample; :mod:`~quatmotion.codec.writer.code`: code every clip in a worker that reads it
   itself (:func:`code_clip` of a :class:`ClipTask`, the models sent to each worker once as
   the batch's context), decoding it back and repairing the frames over ``max_error``
   (:mod:`~quatmotion.codec.writer.verify`); :mod:`~quatmotion.codec.writer.spool`: spool the
   chunks to a temporary file; :mod:`~quatmotion.codec.writer.search`: the passes the
   settings ask for (one, four quality steps, or the ``ratio`` search);
5. :mod:`~quatmotion.codec.writer.write`: write the header and stream the chunks into the
   container (:func:`quatmotion.codec.container.write_container`) atomically.

:func:`~quatmotion.codec.writer.add.add_to_library` (:meth:`Archive.add`) adds clips to an
existing file without re-encoding the clips already in it (their chunks are copied byte for
byte). :mod:`~quatmotion.codec.writer.runner` says where the per-clip jobs run.
"""

from quatmotion.codec.writer.add import add_to_library
from quatmotion.codec.writer.build import build_library, plan_clip_tasks
from quatmotion.codec.writer.code import ClipTask, CodedClip, code_clip
from quatmotion.codec.writer.fit import SharedModels
from quatmotion.codec.writer.runner import runner_of
from quatmotion.codec.writer.scan import ScannedClip, scan_clip

__all__ = [
    "ClipTask",
    "CodedClip",
    "ScannedClip",
    "SharedModels",
    "add_to_library",
    "build_library",
    "code_clip",
    "plan_clip_tasks",
    "runner_of",
    "scan_clip",
]
