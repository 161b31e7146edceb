"""What the env asks of EKF-SLAM's class before any lane is built, from its settings: its
buffers for a workload (docs/reliability.md "Memory") and whether it estimates the wind."""

from __future__ import annotations

from typing import Any

from estimators.ekf.settings import EkfSlamSettings
from estimators.memory import MemoryTerm, Workload, ekf_terms


class MemorySizing:
    """Mixin of :class:`~estimators.ekf.filter.EkfSlamBatch`: the class method the env asks
    (:func:`quadslam_env.estimation.registry.memory_terms`)."""

    @classmethod
    def memory_terms(cls, load: Workload, params: dict[str, Any]) -> list[MemoryTerm]:
        """The covariance, the mean and the map's bookkeeping of ``load``'s lanes
        (:func:`estimators.memory.ekf_terms`), with the vehicle states of ``params``.

        Raises:
            ConfigError: Invalid ``estimator.params`` (as the constructor says it).
            MemoryLimitError: The covariance alone would not fit in its share.
        """
        return ekf_terms(load, EkfSlamSettings.from_dict(params).nv)


class WindStates:
    """Mixin of :class:`~estimators.ekf.filter.EkfSlamBatch`: whether its settings estimate the
    wind, asked before any filter is built
    (:func:`quadslam_env.estimation.registry.estimates_wind`)."""

    @classmethod
    def estimates_wind(cls, params: dict[str, Any]) -> bool:
        """True with ``estimator.params.wind: estimate`` (the snapshot then has ``wind``).

        Raises:
            ConfigError: Invalid ``estimator.params`` (as the constructor says it).
        """
        return EkfSlamSettings.from_dict(params).estimates_wind
