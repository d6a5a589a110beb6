"""Run records: every control cycle as arrays, saved as npz and summarised per stage."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from wholehand.allocation.base import AllocationStatus

FloatArray = npt.NDArray[np.float64]

STATUS_CODES = {status: i for i, status in enumerate(AllocationStatus)}
"""Allocation status -> small integer stored per cycle."""


@dataclass
class RunRecord:
    """Per-cycle arrays of one run (C cycles), plus its metadata.

    Arrays: ``t`` (C,) [s]; ``stage`` (C,) stage index into ``stages``; ``n_contacts`` (C,);
    ``residual_wrench`` (C, 6) [N, N*m]; ``tau`` (C, n_v) [N*m]; ``qp_time``, ``estimate_time``,
    ``cycle_time`` (C,) [s]; ``status`` (C,) codes of :data:`STATUS_CODES`; ``held`` (C,) bool;
    ``p_object`` (C, 3) object origin in the world [m]; ``r_object`` (C, 3) object orientation as a
    rotation vector [rad]; ``q`` (C, n_q) joint positions.

    The estimated contacts of every cycle are stored ragged: ``contact_p``, ``contact_n`` (M, 3)
    positions [m] and object normals, ``contact_f`` (M, 3) commanded forces on the object [N],
    all world frame, ``contact_link`` (M,); cycle i owns rows
    ``contact_offset[i]:contact_offset[i + 1]``.
    """

    meta: dict[str, Any] = field(default_factory=dict)
    stages: list[str] = field(default_factory=list)
    rows: dict[str, list[Any]] = field(default_factory=dict)

    FIELDS = (
        "t", "stage", "n_contacts", "residual_wrench", "tau", "qp_time", "estimate_time",
        "cycle_time", "status", "held", "p_object", "r_object", "q",
    )  # fmt: skip
    CONTACT_FIELDS = ("contact_p", "contact_n", "contact_f", "contact_link")
    _CONTACT_SHAPES = {
        "contact_p": (0, 3),
        "contact_n": (0, 3),
        "contact_f": (0, 3),
        "contact_link": (0,),
    }

    def append(self, **values: Any) -> None:
        """Add one cycle: every name of FIELDS and CONTACT_FIELDS as a keyword."""
        for key in self.FIELDS + self.CONTACT_FIELDS:
            self.rows.setdefault(key, []).append(values[key])

    def arrays(self) -> dict[str, np.ndarray]:
        """The per-cycle arrays and the ragged contact arrays with their offsets."""
        out = {key: np.asarray(self.rows.get(key, [])) for key in self.FIELDS}
        for key in self.CONTACT_FIELDS:
            parts = self.rows.get(key, [])
            out[key] = np.concatenate(parts) if parts else np.zeros(self._CONTACT_SHAPES[key])
        counts = [len(c) for c in self.rows.get("contact_link", [])]
        out["contact_offset"] = np.r_[0, np.cumsum(counts)].astype(np.int64)
        return out

    def contacts_at(self, cycle: int) -> dict[str, np.ndarray]:
        """The contacts of one cycle, keyed as :attr:`CONTACT_FIELDS`."""
        return {key: np.asarray(self.rows[key][cycle]) for key in self.CONTACT_FIELDS}

    def save(self, path: str | Path) -> Path:
        """Write the record as a compressed .npz (metadata as JSON inside)."""
        import json

        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(
            path,
            **self.arrays(),
            stages=np.asarray(self.stages),
            meta=np.asarray(json.dumps(self.meta, default=str)),
        )
        return path

    @classmethod
    def load(cls, path: str | Path) -> RunRecord:
        import json

        with np.load(path, allow_pickle=False) as data:
            record = cls(
                meta=json.loads(str(data["meta"])), stages=[str(s) for s in data["stages"]]
            )
            for key in cls.FIELDS:
                record.rows[key] = list(data[key])
            offsets = data["contact_offset"]
            for key in cls.CONTACT_FIELDS:
                flat = data[key]
                bounds = zip(offsets[:-1], offsets[1:], strict=True)
                record.rows[key] = [flat[a:b] for a, b in bounds]
        return record

    @property
    def held_throughout(self) -> bool:
        held = self.arrays()["held"]
        return bool(held.size and held.all())

    def stage_summary(self) -> list[dict[str, Any]]:
        """Per stage: held or lost, contact count, residual wrench, object displacement."""
        a = self.arrays()
        out = []
        if a["t"].size == 0:
            return out
        p0, r0 = a["p_object"][0], pin.exp3(a["r_object"][0])
        for i, name in enumerate(self.stages):
            rows = np.flatnonzero(a["stage"] == i)
            if rows.size == 0:
                out.append({"stage": name, "held": None})
                continue
            last = rows[-1]
            rotation = pin.log3(pin.exp3(a["r_object"][last]) @ r0.T)
            out.append(
                {
                    "stage": name,
                    "held": bool(a["held"][rows].all()),
                    "contacts_mean": float(a["n_contacts"][rows].mean()),
                    "residual_force_N": float(
                        np.linalg.norm(a["residual_wrench"][rows, :3], axis=1).mean()
                    ),
                    "residual_torque_Nm": float(
                        np.linalg.norm(a["residual_wrench"][rows, 3:], axis=1).mean()
                    ),
                    "displacement_mm": float(1e3 * np.linalg.norm(a["p_object"][last] - p0)),
                    "rotation_deg": float(np.rad2deg(np.linalg.norm(rotation))),
                }
            )
        return out

    def timing_summary(self) -> dict[str, float]:
        """QP and estimate time percentiles [us] and the achieved control rate [Hz]."""
        a = self.arrays()
        us = lambda x, q: float(np.percentile(x, q) * 1e6) if x.size else float("nan")  # noqa: E731
        return {
            "qp_p50_us": us(a["qp_time"], 50),
            "qp_p99_us": us(a["qp_time"], 99),
            "estimate_p50_us": us(a["estimate_time"], 50),
            "estimate_p99_us": us(a["estimate_time"], 99),
            "cycle_p50_us": us(a["cycle_time"], 50),
            "cycle_p99_us": us(a["cycle_time"], 99),
            "achievable_rate_hz": float(1.0 / a["cycle_time"].mean())
            if a["cycle_time"].size
            else float("nan"),
        }
