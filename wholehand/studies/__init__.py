"""The paper's simulation studies as commands: seeded trial lists, a process pool, CSV/JSON/PNG.

``wholehand study NAME`` runs one; :func:`run_study` is the library entry point.
"""

from __future__ import annotations

from wholehand.errors import ConfigError
from wholehand.studies.base import SIZES, Study, TrialJob
from wholehand.studies.consistency import ConsistencyStudy
from wholehand.studies.contacts import ContactsStudy
from wholehand.studies.dexgraspbench import DexGraspBenchStudy
from wholehand.studies.disturbance import DisturbanceStudy
from wholehand.studies.grasp_synthesis import GraspSynthesisStudy
from wholehand.studies.gravity import GravityStudy
from wholehand.studies.k_sweep import KSweepStudy
from wholehand.studies.perturbation import PerturbationStudy
from wholehand.studies.pose_error import PoseErrorStudy
from wholehand.studies.rate import RateStudy
from wholehand.studies.reach import ReachStudy, ReachTableStudy, RobotConditionsStudy
from wholehand.studies.runner import StudyResult, run_study
from wholehand.studies.study_files import TIMING_COLUMNS
from wholehand.studies.tracking import TrackingStudy

STUDIES: dict[str, type[Study]] = {
    cls.name: cls
    for cls in (
        PerturbationStudy,
        PoseErrorStudy,
        KSweepStudy,
        RateStudy,
        DisturbanceStudy,
        ConsistencyStudy,
        ContactsStudy,
        ReachStudy,
        ReachTableStudy,
        RobotConditionsStudy,
        GravityStudy,
        TrackingStudy,
        DexGraspBenchStudy,
        GraspSynthesisStudy,
    )
}
"""Study name -> class, in the paper's priority order."""


def get_study(name: str) -> Study:
    """The study called ``name``; an unknown name raises :class:`ConfigError` listing them."""
    if name not in STUDIES:
        raise ConfigError(f"study {name!r} is unknown; available: {sorted(STUDIES)}")
    return STUDIES[name]()


__all__ = [
    "SIZES",
    "STUDIES",
    "TIMING_COLUMNS",
    "Study",
    "StudyResult",
    "TrialJob",
    "get_study",
    "run_study",
]
