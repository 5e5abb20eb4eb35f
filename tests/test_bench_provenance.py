"""Every benchmark's JSON says what produced it: the command and the machine."""

from __future__ import annotations

import json
import shlex
from pathlib import Path

from quatmotion.bench import provenance


def test_provenance_names_the_command_that_reproduces_the_run():
    record = provenance("qssd", Path("out dir/q.json"), True, 7)
    assert record["benchmark"] == "qssd" and record["quick"] is True and record["seed"] == 7
    assert shlex.split(record["command"]) == [
        "quatmotion", "bench", "qssd", "--out", "out dir/q.json", "--quick", "--seed", "7",
    ]  # fmt: skip
    assert "--quick" not in provenance("io", "io.json", False, 0)["command"]


def test_provenance_describes_the_machine_and_is_json():
    machine = provenance("io", "io.json", False, 0)["machine"]
    assert machine["cpus"] >= 1 and machine["processor"]
    assert machine["python"].count(".") == 2 and "numpy" in machine
    assert json.loads(json.dumps(machine)) == machine
