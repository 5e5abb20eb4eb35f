"""The pose library's keywords before quatmotion 0.5.0, read into what replaced them, with a
:class:`DeprecationWarning` (docs/migration-0.4.md names the release that removes them).

Before, :meth:`~quatmotion.pose.library.PoseLibrary.build_streamed`,
:meth:`~quatmotion.pose.library.PoseLibrary.build_in_memory` and the in-memory
``PoseLibrary.build(clips, ...)`` took the settings as twelve keywords (``metric_name`` for
:attr:`PoseSettings.metric`, ``metric`` for the estimator), where the batch ran as ``workers``
and ``scheduler``, and ``PoseLibrary.add`` how the new clips are read as ``skeleton``,
``units`` and ``joint_map``. Each method's shim here takes them and calls the method with the
new ones; the method's signature (:func:`inspect.signature`) is the new one alone.
"""

from __future__ import annotations

import functools
import os
import warnings
from collections.abc import Callable
from typing import Any, TypeVar

from quatmotion.parallel import Runner
from quatmotion.pose.library.settings import PoseSettings

__all__ = ["old_add", "old_build", "old_build_in_memory", "old_build_streamed"]

F = TypeVar("F", bound=Callable[..., Any])

# keyword before 0.5.0 -> the PoseSettings field it set
_SETTING_OF = {
    "fit_poses": "fit_poses",
    "rank": "rank",
    "n_unlabeled": "n_unlabeled",
    "n_pairs": "n_pairs",
    "seed": "seed",
    "M": "M",
    "ef_construction": "ef_construction",
    "metric_name": "metric",
    "chunk_size": "chunk_size",
    "flush_poses": "flush_poses",
    "index_threads": "index_threads",
}
_BATCH = ("workers", "scheduler")
_READ = ("skeleton", "units", "joint_map", "take")


def _warn(old: str, new: str, stacklevel: int = 4) -> None:
    # stacklevel: this function, the keyword's reader, the shim, the caller
    warnings.warn(
        f"{old} is the name before quatmotion 0.5.0 (removed in 0.6.0): use {new} "
        "(docs/migration-0.4.md)",
        DeprecationWarning,
        stacklevel=stacklevel,
    )


def _take(kwargs: dict[str, Any], names: Any) -> dict[str, Any]:
    return {key: kwargs.pop(key) for key in list(kwargs) if key in names}


def _settings(settings: PoseSettings | None, kwargs: dict[str, Any], where: str) -> Any:
    """``settings`` with the old settings keywords in ``kwargs`` applied (popped, warned;
    validated by :class:`PoseSettings`); ``settings`` as it was when there are none."""
    given = _take(kwargs, _SETTING_OF)
    if not given:
        return settings
    _warn(f"{where}(..., {', '.join(given)}=...)", f"{where}(..., PoseSettings(...))")
    return (settings or PoseSettings()).replace(**{_SETTING_OF[k]: v for k, v in given.items()})


def _runner(kwargs: dict[str, Any], where: str) -> None:
    """The old ``workers``/``scheduler`` keywords in ``kwargs`` as its ``runner`` (warned)."""
    given = _take(kwargs, _BATCH)
    if not given:
        return
    _warn(f"{where}(..., {', '.join(given)}=...)", f"{where}(..., runner=Runner...)")
    runner = kwargs.get("runner")
    if isinstance(runner, Runner):
        raise ValueError("say where the batch runs once: runner, or workers and scheduler")
    scheduler = given.get("scheduler", runner)
    kwargs["runner"] = Runner.resolve(scheduler, workers=given.get("workers"))


def _estimator(kwargs: dict[str, Any], where: str) -> None:
    """The old ``metric`` keyword (an estimator) in ``kwargs`` as its ``estimator`` (warned)."""
    if "metric" in kwargs:
        _warn(f"{where}(..., metric=estimator)", f"{where}(..., estimator=estimator)")
        kwargs["estimator"] = kwargs.pop("metric")


def old_build(build: F) -> F:
    """``PoseLibrary.build``'s shim: ``build(clips, ...)`` without ``out`` (the in-memory
    build, now :meth:`build_in_memory`) and ``workers``/``scheduler``."""

    @functools.wraps(build)
    def shim(cls: Any, sources: Any, out: Any = None, settings: Any = None, **kwargs: Any) -> Any:
        if out is None:
            _warn("PoseLibrary.build(clips, ...)", "PoseLibrary.build_in_memory(clips, ...)", 3)
            return cls.build_in_memory(sources, settings, **kwargs)
        _runner(kwargs, "PoseLibrary.build")
        return build(cls, sources, out, settings, **kwargs)

    return shim  # type: ignore[return-value]


def old_add(add: F) -> F:
    """``PoseLibrary.add``'s shim: ``skeleton``, ``units``, ``joint_map`` (over the stored
    settings' ``read``) and ``workers``/``scheduler``."""

    @functools.wraps(add)
    def shim(cls: Any, path: Any, sources: Any, settings: Any = None, **kwargs: Any) -> Any:
        _runner(kwargs, "PoseLibrary.add")
        given = {k: v for k, v in _take(kwargs, _READ).items() if v is not None}
        if given:
            _warn(f"PoseLibrary.add(..., {', '.join(given)}=...)",
                  "PoseLibrary.add(path, sources, settings) with settings.read", 3)  # fmt: skip
            if "skeleton" in given:
                given["skeleton"] = os.fspath(given["skeleton"])
            if "joint_map" in given:
                given["joint_map"] = tuple(given["joint_map"])
            settings = settings or cls.stored_settings(path)
            if settings is not None:  # else a version-2 library: add says why it refuses
                settings = settings.replace(read=settings.read.replace(**given))
        return add(cls, path, sources, settings, **kwargs)

    return shim  # type: ignore[return-value]


def old_build_streamed(build_streamed: F) -> F:
    """``PoseLibrary.build_streamed``'s shim: the settings as keywords, ``metric`` (the
    estimator) and ``workers``/``scheduler``."""

    @functools.wraps(build_streamed)
    def shim(cls: Any, sources: Any, load: Any, settings: Any = None, **kwargs: Any) -> Any:
        where = "PoseLibrary.build_streamed"
        _estimator(kwargs, where)
        settings = _settings(settings, kwargs, where)
        _runner(kwargs, where)
        return build_streamed(cls, sources, load, settings, **kwargs)

    return shim  # type: ignore[return-value]


def old_build_in_memory(build_in_memory: F) -> F:
    """``PoseLibrary.build_in_memory``'s shim: the settings as keywords and ``metric`` (the
    estimator)."""

    @functools.wraps(build_in_memory)
    def shim(cls: Any, clips: Any, settings: Any = None, **kwargs: Any) -> Any:
        where = "PoseLibrary.build_in_memory"
        _estimator(kwargs, where)
        settings = _settings(settings, kwargs, where)
        return build_in_memory(cls, clips, settings, **kwargs)

    return shim  # type: ignore[return-value]
