"""The README's Python examples run as a user copies them: as a script file (no
``if __name__ == "__main__":`` guard) and piped to ``python -``.

The snippets are read from README.md itself, so a README change that breaks one breaks this
test. Only the data folder is substituted: the README names it as ``../shared/data`` (beside
the project), the test runs in a temporary folder and reads ``$QUATMOTION_DATA``.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from quatmotion import codec
from quatmotion.datasets import data_root
from quatmotion.parallel import SCHEDULER_ENV

README = Path(__file__).resolve().parents[1] / "README.md"
README_DATA = "../shared/data"


def python_snippets() -> list[str]:
    """Every fenced ``python`` block of the README, in order."""
    blocks = re.findall(r"^```python\n(.*?)^```", README.read_text(), flags=re.M | re.S)
    assert blocks, "README.md has no ```python block"
    return blocks


@pytest.mark.needs_data
@pytest.mark.parametrize("how", ["script", "stdin"])
@pytest.mark.parametrize("number", range(len(python_snippets())))
def test_a_readme_python_snippet_runs_as_written(tmp_path: Path, how: str, number: int) -> None:
    snippet = python_snippets()[number]
    assert README_DATA in snippet  # else the substitution below does nothing: update the test
    source = snippet.replace(README_DATA, str(data_root()))
    env = {**os.environ, SCHEDULER_ENV: ""}  # the default: a local pool on every core
    if how == "script":
        script = tmp_path / "example.py"
        script.write_text(source)
        run = {"args": [sys.executable, str(script)]}
    else:
        run = {"args": [sys.executable, "-"], "input": source}
    done = subprocess.run(**run, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "Traceback" not in done.stderr and "leaked" not in done.stderr, done.stderr
    for written in re.findall(r"\"([\w.-]+\.qmz)\"", snippet):
        # what the snippet wrote is a whole library (written before it was opened again)
        with codec.Archive.open(tmp_path / written) as library:
            assert library.names()
