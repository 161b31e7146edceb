"""Compatibility re-export of :mod:`quadslam_env.models.frames` (and ``FloatArray``).

Kept because modules elsewhere import these names from here; new code imports from
:mod:`quadslam_env.models.frames` and :mod:`quadslam_env.types`.
"""

from quadslam_env.models.frames import (
    dcm_euler_partials,
    dcm_from_euler,
    dcm_from_euler_batch,
    euler_from_dcm,
    euler_rate_matrix,
    rot1,
    rot2,
    rot3,
    rotation_angle_between,
    skew,
    wrap_angle,
)
from quadslam_env.types import FloatArray

__all__ = [
    "FloatArray",
    "dcm_euler_partials",
    "dcm_from_euler",
    "dcm_from_euler_batch",
    "euler_from_dcm",
    "euler_rate_matrix",
    "rot1",
    "rot2",
    "rot3",
    "rotation_angle_between",
    "skew",
    "wrap_angle",
]
