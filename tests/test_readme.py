"""The README's Python quick start runs as written, and the package's front door holds what it
says."""

from __future__ import annotations

import re
from pathlib import Path

import wholehand

README = Path(__file__).resolve().parents[1] / "README.md"


def test_the_readme_quick_start_runs(tmp_path, monkeypatch, capsys):
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), re.S)
    assert blocks, "README.md has no Python block"
    monkeypatch.chdir(tmp_path)
    exec(compile(blocks[0], "README.md", "exec"), {})
    held, displacement, phases = capsys.readouterr().out.splitlines()[0].split()
    assert held == "True" and float(displacement) < 20.0 and int(phases) > 2
    assert (tmp_path / "run.mcap").stat().st_size > 10_000


def test_every_public_name_resolves():
    for name in wholehand.__all__:
        assert getattr(wholehand, name) is not None, name
    assert set(wholehand.__all__) <= set(dir(wholehand))
