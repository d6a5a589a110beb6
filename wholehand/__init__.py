"""wholehand: real-time force regulation of whole-hand dexterous grasps.

Conventions used everywhere: poses are 4x4 homogeneous numpy arrays named ``aMb`` (pose of
frame b expressed in frame a; ``w`` world, ``b`` hand base, ``o`` object, ``l`` link), SI units
(m, N, N*m, s, rad), and arrays rather than per-contact objects on the control path.

The main entry points are importable from here (loaded on first use, so that ``import
wholehand`` stays light)::

    import wholehand as wh

    record = wh.run_trial(wh.TrialSpec(object="077_rubiks_cube", theta_deg=60.0))
    print(wh.outcome_of(record).held)
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from wholehand.errors import (
    AssetError,
    ConfigError,
    PluginError,
    WholehandError,
)

if TYPE_CHECKING:
    from wholehand import registry
    from wholehand.allocation.base import Allocation, Allocator
    from wholehand.backends.base import Backend
    from wholehand.backends.command import Command, JointTargets
    from wholehand.contacts.base import ContactEstimator, ContactSet
    from wholehand.loop.control_loop import ControlLoop, Cycle, Observer
    from wholehand.loop.record import Recorder, RunRecord
    from wholehand.loop.regulation import ForceRegulation
    from wholehand.loop.stage import Stage
    from wholehand.models.hand import HandModel, load_hand
    from wholehand.models.kinematics import HandKinematics
    from wholehand.models.object_catalogue import PAPER_OBJECTS, load_object
    from wholehand.models.objects import ObjectModel
    from wholehand.recording.mcap_recording import McapRecorder
    from wholehand.recording.mcap_replay import read_mcap_record
    from wholehand.studies.base import derive_seed, protocol_for, success_stats
    from wholehand.studies.rows import record_row
    from wholehand.studies.runner import run_trials
    from wholehand.trials.outcome import RunOutcome, outcome_of
    from wholehand.trials.trial import TrialSpec, run_trial
    from wholehand.viz.replay import write_html

__version__ = "0.1.0"

_PUBLIC = {
    "registry": "wholehand",
    "Allocation": "wholehand.allocation.base",
    "Allocator": "wholehand.allocation.base",
    "Backend": "wholehand.backends.base",
    "ContactEstimator": "wholehand.contacts.base",
    "ContactSet": "wholehand.contacts.base",
    "Command": "wholehand.backends.command",
    "JointTargets": "wholehand.backends.command",
    "ControlLoop": "wholehand.loop.control_loop",
    "Cycle": "wholehand.loop.control_loop",
    "Observer": "wholehand.loop.control_loop",
    "McapRecorder": "wholehand.recording.mcap_recording",
    "read_mcap_record": "wholehand.recording.mcap_replay",
    "RunOutcome": "wholehand.trials.outcome",
    "outcome_of": "wholehand.trials.outcome",
    "Recorder": "wholehand.loop.record",
    "RunRecord": "wholehand.loop.record",
    "ForceRegulation": "wholehand.loop.regulation",
    "Stage": "wholehand.loop.stage",
    "TrialSpec": "wholehand.trials.trial",
    "run_trial": "wholehand.trials.trial",
    "HandModel": "wholehand.models.hand",
    "load_hand": "wholehand.models.hand",
    "HandKinematics": "wholehand.models.kinematics",
    "PAPER_OBJECTS": "wholehand.models.object_catalogue",
    "load_object": "wholehand.models.object_catalogue",
    "ObjectModel": "wholehand.models.objects",
    "derive_seed": "wholehand.studies.base",
    "protocol_for": "wholehand.studies.base",
    "success_stats": "wholehand.studies.base",
    "record_row": "wholehand.studies.rows",
    "run_trials": "wholehand.studies.runner",
    "write_html": "wholehand.viz.replay",
}
"""Public name -> the module that defines it."""


def __getattr__(name: str) -> Any:
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module 'wholehand' has no attribute {name!r}")
    if name == "registry":
        return importlib.import_module("wholehand.registry")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_PUBLIC))


__all__ = [
    "Allocation",
    "Allocator",
    "AssetError",
    "Backend",
    "Command",
    "ConfigError",
    "ContactEstimator",
    "ContactSet",
    "ControlLoop",
    "Cycle",
    "ForceRegulation",
    "HandKinematics",
    "HandModel",
    "JointTargets",
    "McapRecorder",
    "ObjectModel",
    "Observer",
    "PAPER_OBJECTS",
    "PluginError",
    "Recorder",
    "RunOutcome",
    "RunRecord",
    "Stage",
    "TrialSpec",
    "WholehandError",
    "__version__",
    "derive_seed",
    "load_hand",
    "load_object",
    "outcome_of",
    "protocol_for",
    "read_mcap_record",
    "record_row",
    "registry",
    "run_trial",
    "run_trials",
    "success_stats",
    "write_html",
]
