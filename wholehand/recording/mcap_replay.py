"""MCAP recordings of :mod:`wholehand.recording.mcap_recording` read back as run records, for
``wholehand view run.mcap``.

Decoded with ``mcap`` and ``mcap_ros2``'s CDR decoder, not the rosbags that wrote them, so that
reading a recording checks its writing.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from wholehand.errors import ConfigError
from wholehand.loop.record import RunRecord
from wholehand.recording.mcap_recording import ARROW_SCALE

FloatArray = npt.NDArray[np.float64]


MCAP_MAGIC = b"\x89MCAP0\r\n"
"""The first eight bytes of every MCAP file."""


def _messages(path: Path) -> tuple[list[tuple[str, float, Any]], str]:
    """(topic, log time [s], decoded message) of every message, in log time order, and a note
    that the file was cut short ("" if it was not).

    A file that a crash, SIGKILL or a full disk cut short has no summary or footer: it is read
    record by record up to the cut (every chunk written whole before it), and the note says
    where it ends.

    Raises:
        ConfigError: the file is empty, no MCAP file, or holds messages that are not ROS 2 CDR
            (another tool's recording).
    """
    from mcap.exceptions import DecoderNotFoundError, McapError
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(path, "rb") as f:
        head = f.read(len(MCAP_MAGIC))
    if not head:
        raise ConfigError(f"{path} is empty: the recording holds nothing (was it ever written?)")
    if head != MCAP_MAGIC:
        hint = "; a zip or .npz file, a run record? Name it .npz" if head[:2] == b"PK" else ""
        raise ConfigError(f"{path} is no MCAP file: it starts with {head!r}{hint}")
    try:
        with open(path, "rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            out = [
                (channel.topic, 1e-9 * message.log_time, decoded)
                for _, channel, message, decoded in reader.iter_decoded_messages(
                    log_time_order=True
                )
            ]
        return out, ""
    except DecoderNotFoundError as err:
        raise ConfigError(
            f"{path} is no wholehand recording: its messages are not ROS 2 CDR ({err})"
        ) from None
    except (McapError, EOFError, ValueError, KeyError, struct.error):
        return _messages_to_the_cut(path)


def _messages_to_the_cut(path: Path) -> tuple[list[tuple[str, float, Any]], str]:
    """:func:`_messages` of a file without a footer: every record up to the first that cannot
    be read."""
    from mcap.exceptions import DecoderNotFoundError
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader
    from mcap_ros2.decoder import DecoderFactory

    factory = DecoderFactory()
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    decoders: dict[int, Any] = {}
    out: list[tuple[str, float, Any]] = []
    with open(path, "rb") as f:
        records = StreamReader(f).records
        while True:
            try:
                record = next(records)
            except StopIteration:
                break
            except Exception:  # the cut: a record (or chunk) written in part
                break
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message) and record.channel_id in channels:
                channel = channels[record.channel_id]
                if record.channel_id not in decoders:
                    decoder = factory.decoder_for(
                        channel.message_encoding, schemas.get(channel.schema_id)
                    )
                    if decoder is None:
                        raise ConfigError(
                            f"{path} is no wholehand recording: its messages on {channel.topic}"
                            f" are {channel.message_encoding!r}, not ROS 2 CDR"
                        ) from DecoderNotFoundError(channel.message_encoding)
                    decoders[record.channel_id] = decoder
                decoded = decoders[record.channel_id](record.data)
                out.append((channel.topic, 1e-9 * record.log_time, decoded))
    out.sort(key=lambda m: m[1])
    end = f"t = {out[-1][1]:.3f} s" if out else "before its first message"
    note = (
        f"{path} was cut short (no footer: the writing process ended before closing it); "
        f"read up to the cut, {len(out)} messages, to {end}"
    )
    return out, note


def read_mcap_record(path: str | Path) -> RunRecord:
    """A recording of :class:`McapRecorder` as a :class:`RunRecord` (what ``wholehand view``
    replays): per cycle the joint positions, the object's and the hand base's poses, the
    contacts and their forces, the torques, the residual wrench, the stage and status. A
    recording cut short is read up to the cut, and ``meta["cut_short"]`` says so.

    Raises:
        ConfigError: no such file, an empty or damaged file, another tool's recording.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"no MCAP recording at {path}; write one with --record run.mcap")
    messages, cut = _messages(path)
    info, cycles = _cycles(messages)
    if not info:
        why = f" ({cut})" if cut else ""
        raise ConfigError(f"{path} is no wholehand recording: it has no /wholehand/run_info{why}")
    if cut and cycles and (len(cycles) == 1 or set(cycles[-1]) != set(cycles[-2])):
        cycles.pop()  # the cycle the cut went through, short of some of its messages
    record = RunRecord(phases=["run"])
    record.meta = {"spec": {"hand": info["hand"], "object": info["object"]}, **info}
    if not record.meta.get("table"):
        record.meta.pop("table", None)
    for cycle in cycles:
        _append(record, cycle, info)
    if cut:
        record.meta["cut_short"] = cut
    return record


def _cycles(messages: list[tuple[str, float, Any]]) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The run's info and its cycles (each begun by a ``/tf`` message) from the messages."""
    info: dict[str, Any] = {}
    cycles: list[dict[str, Any]] = []
    for topic, t, msg in messages:
        if topic == "/wholehand/run_info":
            info = json.loads(msg.data)
        elif topic == "/tf":
            cycles.append(
                {"t": t, "tf": {tf.child_frame_id: tf.transform for tf in msg.transforms}}
            )
        elif cycles:
            _add_to_cycle(cycles[-1], topic, msg)
    return info, cycles


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
