"""The report of ``wholehand hand check`` (:func:`wholehand.models.check.check_hand`): what a
hand folder gives the controller, and each finding with its fix."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from wholehand.models.hand import HandModel


@dataclass
class Finding:
    """One problem found, and how to fix it."""

    severity: str
    """``error`` (the hand cannot be used), ``warning`` (it runs, probably not as meant) or
    ``note``."""
    what: str
    fix: str


@dataclass
class HandReport:
    """The result of :func:`check_hand`; :meth:`as_dict` is JSON-serialisable."""

    path: Path
    summary: dict[str, Any] = field(default_factory=dict)
    joints: list[dict[str, Any]] = field(default_factory=list)
    findings: list[Finding] = field(default_factory=list)
    hand: HandModel | None = None

    @property
    def ok(self) -> bool:
        """No error among the findings."""
        return not any(f.severity == "error" for f in self.findings)

    def add(self, severity: str, what: str, fix: str) -> None:
        self.findings.append(Finding(severity, what, fix))

    def as_dict(self) -> dict[str, Any]:
        return {
            "path": str(self.path),
            "ok": self.ok,
            "summary": self.summary,
            "joints": self.joints,
            "findings": [f.__dict__ for f in self.findings],
        }
