"""The estimator boundary (docs/design.md §5): the belief the env reads, the protocols an
estimator implements and those of its optional abilities, the one adapter for an estimator of
one vehicle, the registry that finds estimators by name, and the health check of a belief.

This package belongs to the ground floor: it imports the models and measurement types only,
never an estimator or the env, so estimators and the env both build on it.
"""

from quadslam_env.estimation.health import HEALTH_PROBLEMS, health_codes, position_std
from quadslam_env.estimation.integrity import MonitorSettings, protection_levels
from quadslam_env.estimation.lane_loop import LaneLoop, ParticleLaneLoop
from quadslam_env.estimation.memory import MemoryLimitError, MemoryTerm, Workload
from quadslam_env.estimation.protocol import (
    AssociatesUnlabeled,
    BatchEstimator,
    ChecksMemory,
    EstimatesState,
    Estimator,
    FusesLandmarks,
    HasFullState,
    HasParticles,
    IntArray,
    KnownMaps,
    LabelsReturns,
    ModelsDrag,
    MonitorsIntegrity,
    ReportsLandmarkCovariances,
    ReservesLandmarks,
    ShowsParticles,
    TakesLateScans,
    TakesVehicle,
    TakesWind,
    UsesTruth,
    UsesVehicle,
)
from quadslam_env.estimation.registry import (
    ENTRY_POINT_GROUP,
    associates_unlabeled,
    available,
    copyable,
    estimates_wind,
    estimator_flag,
    fuses_landmarks,
    make,
    memory_terms,
    models_drag,
    monitors_integrity,
    register,
    takes_late_scans,
)
from quadslam_env.estimation.snapshot import BatchEstimate

__all__ = [
    "ENTRY_POINT_GROUP",
    "HEALTH_PROBLEMS",
    "AssociatesUnlabeled",
    "BatchEstimate",
    "BatchEstimator",
    "ChecksMemory",
    "EstimatesState",
    "Estimator",
    "FusesLandmarks",
    "HasFullState",
    "HasParticles",
    "IntArray",
    "KnownMaps",
    "LabelsReturns",
    "LaneLoop",
    "MemoryLimitError",
    "MemoryTerm",
    "ModelsDrag",
    "MonitorSettings",
    "MonitorsIntegrity",
    "ParticleLaneLoop",
    "ReportsLandmarkCovariances",
    "ReservesLandmarks",
    "ShowsParticles",
    "TakesLateScans",
    "TakesVehicle",
    "TakesWind",
    "UsesTruth",
    "UsesVehicle",
    "Workload",
    "associates_unlabeled",
    "available",
    "copyable",
    "estimates_wind",
    "estimator_flag",
    "fuses_landmarks",
    "health_codes",
    "make",
    "memory_terms",
    "models_drag",
    "monitors_integrity",
    "position_std",
    "protection_levels",
    "register",
    "takes_late_scans",
]
