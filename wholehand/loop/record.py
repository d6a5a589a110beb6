"""Run records: every control cycle as arrays, saved as npz and summarised per protocol phase.

:class:`Recorder` is the loop observer that fills a :class:`RunRecord`.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from wholehand.errors import ConfigError
from wholehand.loop.control_loop import ControlLoop, Cycle, Observer

if TYPE_CHECKING:
    from wholehand.loop.grasp_loss import GraspLossMonitor

FloatArray = npt.NDArray[np.float64]


class PhaseSource(Protocol):
    """What the recorder reads of a perturbation protocol's driver
    (:class:`~wholehand.trials.protocol.ProtocolDriver`): its phases and the current one."""

    @property
    def phase_names(self) -> list[str]: ...

    @property
    def phase_index(self) -> int: ...


@dataclass
class RunRecord:
    """Per-cycle arrays of one run (C cycles), plus its metadata.

    Arrays: ``t`` (C,) joint stamp [s]; ``stamp_object`` (C,) stamp of the object pose the
    controller used [s] (older than ``t`` behind a tracker); ``phase`` (C,) protocol phase
    index into ``phases``; ``stage`` (C,) name of the loop stage that ran; ``n_contacts`` (C,);
    ``residual_wrench`` (C, 6) [N, N*m]; ``tau`` (C, n_v) commanded torques [N*m]; ``qp_time``,
    ``estimate_time``, ``cycle_time`` (C,) [s]; ``status`` (C,) the cycle's status by name;
    ``held`` (C,) bool;
    ``p_object`` (C, 3) object origin in the world [m]; ``r_object`` (C, 3) object orientation as a
    rotation vector [rad]; ``q`` (C, n_q) joint positions; ``p_base``, ``r_base`` (C, 3) the hand
    base's pose likewise (it moves on a floating wrist).

    The estimated contacts of every cycle are stored ragged: ``contact_p``, ``contact_n`` (M, 3)
    positions [m] and object normals, ``contact_f`` (M, 3) commanded forces on the object [N],
    all world frame, ``contact_link`` (M,); cycle i owns rows
    ``contact_offset[i]:contact_offset[i + 1]``.
    """

    meta: dict[str, Any] = field(default_factory=dict)
    phases: list[str] = field(default_factory=list)
    """Names of the protocol phases (one, ``"run"``, without a protocol)."""
    rows: dict[str, list[Any]] = field(default_factory=dict)

    FIELDS = (
        "t",
        "stamp_object",
        "phase",
        "stage",
        "n_contacts",
        "residual_wrench",
        "tau",
        "qp_time",
        "estimate_time",
        "cycle_time",
        "status",
        "held",
        "p_object",
        "r_object",
        "q",
        "p_base",
        "r_base",
    )
    OPTIONAL_FIELDS = ("p_base", "r_base")
    """Fields that records of older versions lack (loaded as the hand's mount pose, None)."""
    CONTACT_FIELDS = ("contact_p", "contact_n", "contact_f", "contact_link")
    _CONTACT_SHAPES = {
        "contact_p": (0, 3),
        "contact_n": (0, 3),
        "contact_f": (0, 3),
        "contact_link": (0,),
    }

    def append(self, **values: Any) -> None:
        """Add one cycle: every name of FIELDS and CONTACT_FIELDS as a keyword (those of
        OPTIONAL_FIELDS may be left out, then for every cycle)."""
        for key in self.FIELDS + self.CONTACT_FIELDS:
            if key in self.OPTIONAL_FIELDS and key not in values:
                continue
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
            allow_pickle=False,
            **self.arrays(),
            phases=np.asarray(self.phases),
            meta=np.asarray(json.dumps(self.meta, default=str)),
        )
        return path

    @classmethod
    def load(cls, path: str | Path) -> RunRecord:
        """The record saved at ``path`` (:meth:`save`).

        Raises:
            ConfigError: no such file, or one that is not a whole run record (truncated, another
                kind of file, another version), named with what is wrong.
        """
        if not Path(path).is_file():
            raise ConfigError(f"{path}: no such run record; record one with `wholehand run --save`")
        try:
            return cls._read(path)
        except ConfigError:
            raise
        except (zipfile.BadZipFile, EOFError, OSError) as err:
            raise ConfigError(
                f"{path}: not a readable run record (a truncated or damaged .npz file: "
                f"{type(err).__name__}: {err}); record the run again"
            ) from err
        except (ValueError, KeyError, TypeError) as err:
            raise ConfigError(
                f"{path}: not a run record ({type(err).__name__}: {err}); give a file saved by "
                "`wholehand run --save` or `wholehand reach --record`"
            ) from err

    @classmethod
    def _read(cls, path: str | Path) -> RunRecord:
        import json

        with np.load(path, allow_pickle=False) as data:
            if not hasattr(data, "files"):
                raise ConfigError(f"{path}: a single numpy array, not a run record (.npz)")
            if "phases" not in data:
                raise ConfigError(
                    f"{path}: not a run record of this wholehand version (no 'phases'); "
                    "record the run again with `wholehand run --save`"
                )
            record = cls(
                meta=json.loads(str(data["meta"])), phases=[str(s) for s in data["phases"]]
            )
            for key in cls.FIELDS:
                if key in data or key not in cls.OPTIONAL_FIELDS:
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

    def phase_summary(self) -> list[dict[str, Any]]:
        """Per phase: held or lost, contact count, residual wrench, object displacement."""
        a = self.arrays()
        out: list[dict[str, Any]] = []
        if a["t"].size == 0:
            return out
        p0, r0 = a["p_object"][0], pin.exp3(a["r_object"][0])
        for i, name in enumerate(self.phases):
            rows = np.flatnonzero(a["phase"] == i)
            if rows.size == 0:
                out.append({"phase": name, "held": None})
                continue
            last = rows[-1]
            rotation = pin.log3(pin.exp3(a["r_object"][last]) @ r0.T)
            out.append(
                {
                    "phase": name,
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


class Recorder(Observer):
    """Fills a :class:`RunRecord` with one row per cycle: the true object pose and q, the stage's
    contacts and allocation, the applied torque, the grasp-loss verdict.

    Args:
        loss: the grasp-loss monitor whose verdict is recorded (it must come before the
            recorder among the loop's observers).
        protocol: the protocol driver whose phase is recorded (None: one phase, ``"run"``).
        meta: the record's metadata.
    """

    def __init__(
        self,
        loss: GraspLossMonitor,
        protocol: PhaseSource | None = None,
        meta: dict[str, Any] | None = None,
    ) -> None:
        self.loss, self.protocol = loss, protocol
        phases = protocol.phase_names if protocol is not None else ["run"]
        self.record = RunRecord(meta=dict(meta or {}), phases=phases)

    def on_start(self, loop: ControlLoop) -> None:
        self.record.meta.setdefault("control_rate", loop.rate)

    def on_cycle(self, cycle: Cycle) -> str | None:
        out, truth = cycle.output, cycle.truth
        contacts, allocation = out.contacts, out.allocation
        q = _nan_unless(truth.q, (cycle.context.hand.nq,))
        wMo = _nan_unless(truth.wMo, (4, 4))
        base = _nan_unless(truth.wMb, (4, 4))
        self.record.append(
            t=truth.stamp_q,
            stamp_object=cycle.context.obs.stamp_object,
            phase=self.protocol.phase_index if self.protocol is not None else 0,
            stage=cycle.stage,
            n_contacts=0 if contacts is None else len(contacts),
            residual_wrench=np.zeros(6) if allocation is None else allocation.residual_wrench,
            tau=cycle.command.tau,
            qp_time=0.0 if allocation is None else allocation.solve_time,
            estimate_time=out.estimate_time,
            cycle_time=cycle.cycle_time,
            status=out.status,
            held=self.loss.held,
            p_object=wMo[:3, 3].copy(),
            r_object=pin.log3(wMo[:3, :3]) if np.isfinite(wMo).all() else np.full(3, np.nan),
            q=q,
            p_base=base[:3, 3].copy(),
            r_base=pin.log3(base[:3, :3]) if np.isfinite(base).all() else np.full(3, np.nan),
            contact_p=_EMPTY3 if contacts is None else contacts.p_world,
            contact_n=_EMPTY3 if contacts is None else contacts.n_world,
            contact_f=_EMPTY3 if allocation is None else allocation.f_world,
            contact_link=_EMPTY_LINK if contacts is None else contacts.link,
        )
        return None


def _nan_unless(value: Any, shape: tuple[int, ...]) -> FloatArray:
    """``value`` as floats if it has ``shape`` and is numeric, else NaN of that shape (a bad
    observation is recorded as unknown, never as garbage of another shape)."""
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        return np.full(shape, np.nan)
    return arr if arr.shape == shape else np.full(shape, np.nan)


_EMPTY3 = np.zeros((0, 3))
_EMPTY_LINK = np.zeros(0, dtype=np.intp)
