"""docs/architecture.md stays true: every module, name and path it cites exists, and every
package of quatmotion is drawn in it."""

from __future__ import annotations

import importlib
import pkgutil
import re
from pathlib import Path

import pytest

import quatmotion

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "architecture.md"
PACKAGE = Path(quatmotion.__file__).parent
TOP_NAMES = {m.name for m in pkgutil.iter_modules([str(PACKAGE)])}


def _cited() -> list[str]:
    spans = re.findall(r"`([^`\n]+)`", DOC.read_text(encoding="utf-8"))
    return sorted({s.strip() for s in spans})


def _dotted_names() -> list[str]:
    """Cited names that start with one of quatmotion's modules (``pose.library.PoseLibrary``)."""
    names = []
    for span in _cited():
        match = re.fullmatch(r"(?:quatmotion\.)?([A-Za-z_]\w*(?:\.[A-Za-z_]\w*)*)(\(.*\))?", span)
        if match and match.group(1).split(".")[0] in TOP_NAMES:
            names.append(match.group(1))
    return names


def _resolve(dotted: str) -> object:
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj: object = importlib.import_module("quatmotion." + ".".join(parts[:cut]))
        except ModuleNotFoundError:
            continue
        for attribute in parts[cut:]:
            obj = getattr(obj, attribute)
        return obj
    raise ModuleNotFoundError(dotted)


def test_the_doc_cites_names_at_all():
    assert len(_dotted_names()) > 30


@pytest.mark.parametrize("dotted", _dotted_names())
def test_every_module_and_name_the_doc_cites_exists(dotted):
    try:
        _resolve(dotted)
    except (ModuleNotFoundError, AttributeError) as error:
        pytest.fail(f"docs/architecture.md cites `{dotted}`, which does not exist: {error}")


def test_every_path_the_doc_cites_exists():
    paths = [s for s in _cited() if re.fullmatch(r"[\w.\-]+(/[\w.\-]+)+/?", s)]
    assert paths, "the doc cites no path"
    missing = [p for p in paths if not any((base / p).exists() for base in (ROOT, PACKAGE))]
    assert missing == []


def test_every_package_and_module_of_quatmotion_is_in_the_doc():
    text = DOC.read_text(encoding="utf-8")
    absent = [
        name
        for name in sorted(TOP_NAMES)
        if name != "__main__" and not re.search(rf"\b{re.escape(name)}\b", text)
    ]
    assert absent == []
