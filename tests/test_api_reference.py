"""The docs site builds with its API reference, and the reference covers every public name."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import wholehand

ROOT = Path(__file__).resolve().parents[1]


def test_the_api_reference_names_every_public_name():
    page = (ROOT / "docs" / "api.md").read_text()
    documented = {m.rsplit(".", 1)[-1] for m in re.findall(r"^::: ([\w.]+)$", page, re.M)}
    public = set(wholehand.__all__) - {"__version__"}
    assert public - documented == set(), "add them to docs/api.md"
    assert documented - public == set(), "not public: export them or leave them out"


def test_the_docs_site_builds_without_a_warning(tmp_path):
    """mkdocs --strict: a docstring mkdocstrings cannot read, a page missing from the nav or a
    broken anchor fails the build."""
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d", str(tmp_path / "site")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-4000:]
    html = (tmp_path / "site" / "api" / "index.html").read_text()
    assert 'id="wholehand.trials.trial.run_trial"' in html
