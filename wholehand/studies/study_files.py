"""A study's rows on disk: ``trials.csv`` (read back with types) and the journal ``rows.jsonl``
(one JSON row a line, appended as trials finish, so an interrupted run loses nothing)."""

from __future__ import annotations

import csv
import dataclasses
import json
import logging
import math
import os
import re
from pathlib import Path
from typing import IO, Any

import numpy as np

from wholehand.errors import ConfigError
from wholehand.trials.trial import TrialSpec

log = logging.getLogger(__name__)

TIMING_COLUMNS = (
    "wall_time_s",
    "qp_p50_us",
    "cycle_mean_us",
    "cycle_p99_us",
    "cycle_max_us",
    "control_rate_hz",
)
"""Wall-clock columns of ``trials.csv``: they vary from run to run (not part of determinism)."""

TEXT_COLUMNS = ("kind", "failure_stage", "error") + tuple(
    f.name
    for f in dataclasses.fields(TrialSpec)
    if isinstance(f.default, str) or f.default_factory is dict
)
"""Columns :func:`read_csv` keeps as strings, an empty cell included (``""``, not None): the
job kind, the failure stage, the error and the spec's names and JSON parameter dicts."""

JOURNAL_NAME = "rows.jsonl"
"""Journal of a study folder: every finished row as one JSON line, appended as it arrives."""


def columns_of(rows: list[dict[str, Any]]) -> list[str]:
    """CSV header: every key in first-seen order, timing columns last."""
    cols: list[str] = []
    for r in rows:
        cols += [k for k in r if k not in cols]
    return [c for c in cols if c not in TIMING_COLUMNS] + [c for c in TIMING_COLUMNS if c in cols]


def write_csv(rows: list[dict[str, Any]], path: str | Path) -> Path:
    """Write ``rows`` as CSV (header :func:`columns_of`, None as an empty cell); read it back
    with :func:`read_csv`. The file is replaced at once (written aside, then renamed), so an
    interruption never leaves half a ``trials.csv``."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=columns_of(rows), restval="")
        writer.writeheader()
        for r in rows:
            writer.writerow({k: ("" if v is None else v) for k, v in r.items()})
    os.replace(tmp, path)
    return path


_INT = re.compile(r"[-+]?(0|[1-9][0-9]*)")
"""An int as ``str(int)`` writes it (no leading zeros: ``"077"`` stays a string)."""
_FLOAT = re.compile(
    r"[-+]?(([0-9]+\.[0-9]*|\.[0-9]+)([eE][-+]?[0-9]+)?|[0-9]+[eE][-+]?[0-9]+|nan|inf)"
)
"""A float as ``str(float)`` writes it: with a point or an exponent, or nan / inf."""


def _cell(text: str) -> Any:
    """A CSV cell written by :func:`write_csv` as the Python value it came from."""
    if text == "":
        return None
    if text in ("True", "False"):
        return text == "True"
    if _INT.fullmatch(text):
        return int(text)
    if _FLOAT.fullmatch(text):
        return float(text)
    return text


def read_csv(path: str | Path, damaged: list[int] | None = None) -> list[dict[str, Any]]:
    """Rows of a CSV written by :func:`write_csv`, typed back: ``True``/``False`` as booleans,
    integers (no leading zeros) as int, numbers with a point or an exponent, ``nan`` and
    ``inf`` as float, an empty cell as None, anything else as a string. :data:`TEXT_COLUMNS`
    always stay strings (``""`` included), so the spec's JSON parameter dicts compare equal to
    :func:`spec_columns`.

    A line with fewer cells than the header has columns (cut short) is damaged: with a
    ``damaged`` list its line number goes there and the line is skipped.

    Raises:
        ConfigError: a line has more cells than the header has columns, or, without
            ``damaged``, fewer.
    """
    path = Path(path)
    rows: list[dict[str, Any]] = []
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        for raw in reader:
            if None in raw:
                raise ConfigError(
                    f"{path}, line {reader.line_num}: more cells than the header's "
                    f"{len(reader.fieldnames or ())} columns; the file is not a trials.csv "
                    "written by wholehand (remove it, or the line, to go on)"
                )
            if None in raw.values():
                if damaged is None:
                    raise ConfigError(
                        f"{path}, line {reader.line_num}: fewer cells than the header's "
                        f"{len(reader.fieldnames or ())} columns (cut short?); remove the line"
                    )
                damaged.append(reader.line_num)
                continue
            rows.append({k: (v if k in TEXT_COLUMNS else _cell(v or "")) for k, v in raw.items()})
    return rows


def read_journal(path: str | Path) -> list[dict[str, Any]]:
    """Rows of a journal (:data:`JOURNAL_NAME`), in the order they were appended. A line that is
    not a JSON object (e.g. cut short when the run was killed) is skipped with a warning."""
    path = Path(path)
    rows: list[dict[str, Any]] = []
    with open(path, encoding="utf-8") as fh:
        for number, line in enumerate(fh, start=1):
            if not line.strip():
                continue
            try:
                row = json.loads(line)
            except json.JSONDecodeError:
                row = None
            if not isinstance(row, dict):
                log.warning("%s, line %d: not a JSON row (cut short?); skipped", path, number)
                continue
            rows.append(row)
    return rows


def folder_rows(
    folder: Path, damaged: list[int] | None = None
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """(rows of ``trials.csv``, rows of the journal) of a folder, each empty if absent; the
    line numbers of damaged lines of ``trials.csv`` go to ``damaged`` (:func:`read_csv`)."""
    csv_path, journal_path = folder / "trials.csv", folder / JOURNAL_NAME
    from_csv = read_csv(csv_path, damaged) if csv_path.exists() else []
    from_journal = read_journal(journal_path) if journal_path.exists() else []
    return from_csv, from_journal


def json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    return str(value)


def journal_line(row: dict[str, Any]) -> str:
    """One journal line: the row as JSON (NaN and inf as Python's json writes them)."""
    return json.dumps(row, default=json_default) + "\n"


def open_journal(path: Path, fresh: bool) -> IO[str]:
    """The journal opened for appending (emptied first if ``fresh``); a last line cut short by a
    killed run is ended so that the next row starts on a line of its own."""
    if fresh or not path.exists():
        return open(path, "w", encoding="utf-8")
    cut_short = False
    if path.stat().st_size:
        with open(path, "rb") as raw:
            raw.seek(-1, os.SEEK_END)
            cut_short = raw.read(1) != b"\n"
    fh = open(path, "a", encoding="utf-8")  # closed by run_study
    if cut_short:
        fh.write("\n")
    return fh


def json_safe(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    if isinstance(value, np.generic):
        return json_safe(value.item())
    return value
