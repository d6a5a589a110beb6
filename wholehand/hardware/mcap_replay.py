"""MCAP recordings of :mod:`wholehand.hardware.mcap_recording` read back as run records, for
``wholehand view run.mcap``.

Decoded with ``mcap`` and ``mcap_ros2``'s CDR decoder, not the rosbags that wrote them, so that
reading a recording checks its writing.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from wholehand.errors import ConfigError
from wholehand.hardware.mcap_recording import ARROW_SCALE
from wholehand.loop.record import RunRecord

FloatArray = npt.NDArray[np.float64]


def _messages(path: Path) -> Iterator[tuple[str, float, Any]]:
    """(topic, log time [s], decoded message) of every message, in log time order."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True):
            yield channel.topic, 1e-9 * message.log_time, decoded


def read_mcap_record(path: str | Path) -> RunRecord:
    """A recording of :class:`McapRecorder` as a :class:`RunRecord` (what ``wholehand view``
    replays): per cycle the joint positions, the object's and the hand base's poses, the
    contacts and their forces, the torques, the residual wrench, the stage and status."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"no MCAP recording at {path}; write one with --record run.mcap")
    record = RunRecord(phases=["run"])
    info: dict[str, Any] = {}
    cycle: dict[str, Any] = {}
    for topic, t, msg in _messages(path):
        if topic == "/wholehand/run_info":
            info = json.loads(msg.data)
            record.meta = {"spec": {"hand": info["hand"], "object": info["object"]}, **info}
            if not record.meta.get("table"):
                record.meta.pop("table", None)
        elif topic == "/tf":
            if cycle:
                _append(record, cycle, info)
            cycle = {"t": t, "tf": {tf.child_frame_id: tf.transform for tf in msg.transforms}}
        elif cycle:
            _add_to_cycle(cycle, topic, msg)
    if cycle:
        _append(record, cycle, info)
    if not info:
        raise ConfigError(f"{path} is no wholehand recording: it has no /wholehand/run_info")
    return record


def _add_to_cycle(cycle: dict[str, Any], topic: str, msg: Any) -> None:
    """Put what a cycle's message on ``topic`` says into ``cycle`` (other topics: nothing)."""
    if topic == "/joint_states":
        cycle["q"] = np.asarray(msg.position, dtype=float)
        cycle["tau"] = np.asarray(msg.effort, dtype=float)
    elif topic == "/wholehand/contacts":
        cycle["contacts"] = {m.ns: m for m in msg.markers}
    elif topic == "/wholehand/residual_wrench":
        f, m = msg.wrench.force, msg.wrench.torque
        cycle["wrench"] = [f.x, f.y, f.z, m.x, m.y, m.z]
    elif topic == "/wholehand/status":
        cycle["stage"], _, cycle["status"] = msg.data.partition(": ")


def _matrix(transform: Any) -> FloatArray:
    r, v = transform.rotation, transform.translation
    M = np.eye(4)
    M[:3, :3] = pin.Quaternion(r.w, r.x, r.y, r.z).toRotationMatrix()
    M[:3, 3] = [v.x, v.y, v.z]
    return M


def _append(record: RunRecord, cycle: dict[str, Any], info: dict[str, Any]) -> None:
    tf = cycle["tf"]
    wMo = _matrix(tf["object"]) if "object" in tf else np.eye(4)
    base = info.get("base_link")
    wMb = _matrix(tf[base]) if base in tf else np.eye(4)
    scale = float(info.get("arrow_scale_m_per_N", ARROW_SCALE))
    markers = cycle.get("contacts", {})
    p = np.zeros((0, 3))
    f = np.zeros((0, 3))
    if "forces" in markers:
        line = markers["forces"]
        ends = np.array([[v.x, v.y, v.z] for v in line.points], dtype=float).reshape(-1, 2, 3)
        p = ends[:, 0]
        grey = np.array([c.r == c.g == c.b for c in line.colors[::2]], dtype=bool)
        f = np.where(grey[:, None], 0.0, (ends[:, 1] - ends[:, 0]) / scale)
    tau = cycle.get("tau", np.zeros(0))
    record.append(
        t=cycle["t"],
        stamp_object=cycle["t"],
        phase=0,
        stage=cycle.get("stage", ""),
        n_contacts=len(p),
        residual_wrench=np.asarray(cycle.get("wrench", [np.nan] * 6), dtype=float),
        tau=tau,
        qp_time=np.nan,
        estimate_time=np.nan,
        cycle_time=np.nan,
        status=cycle.get("status", ""),
        held=True,
        p_object=wMo[:3, 3],
        r_object=pin.log3(wMo[:3, :3]),
        q=cycle.get("q", np.zeros(0)),
        p_base=wMb[:3, 3],
        r_base=pin.log3(wMb[:3, :3]),
        contact_p=p,
        contact_n=np.zeros_like(p),
        contact_f=f,
        contact_link=np.full(len(p), -1, dtype=np.int64),
    )
