"""``vehicle.physics_dt_s`` must divide the control period ``1 / episode.control_hz`` into a
whole number of RK4 substeps (docs/env.md), up to float rounding."""

from __future__ import annotations

import re

import pytest

from quadslam_env.config.scenario import load_scenario
from quadslam_env.schema import ConfigError


@pytest.mark.parametrize(
    ("control_hz", "physics_dt_s", "substeps"),
    [
        (100.0, 0.002, 5),  # 0.01 / 0.002 = 5.000000000000001 in floating point
        (100.0, 0.01, 1),
        (50.0, 0.002, 10),
        (40.0, 0.0025, 10),
        (30.0, 1.0 / 30.0 / 7.0, 7),  # a substep no decimal writes exactly
        (100.0, 0.001 / 3.0, 30),
        (500.0, 0.002, 1),
    ],
)
def test_a_substep_that_divides_the_control_period_is_accepted(
    control_hz: float, physics_dt_s: float, substeps: int
) -> None:
    cfg = load_scenario(
        None, {"episode": {"control_hz": control_hz}, "vehicle": {"physics_dt_s": physics_dt_s}}
    )
    assert cfg.vehicle.physics_dt_s == physics_dt_s
    assert round(1.0 / (control_hz * physics_dt_s)) == substeps


@pytest.mark.parametrize(
    ("control_hz", "physics_dt_s", "shorter"),
    [
        (100.0, 0.003, 0.0025),  # 3.33 substeps: four of 2.5 ms would do
        (100.0, 0.0021, 0.002),
        (100.0, 0.002 * (1 + 1e-6), 0.002),  # beyond rounding
        (40.0, 0.002, 0.0019230769),  # the default substep at 40 Hz: 12.5 substeps
        (1000.0, 0.002, 0.001),  # longer than the control period
    ],
)
def test_a_substep_that_does_not_divide_the_period_is_a_config_error(
    control_hz: float, physics_dt_s: float, shorter: float
) -> None:
    overrides = {"episode": {"control_hz": control_hz}, "vehicle": {"physics_dt_s": physics_dt_s}}
    with pytest.raises(ConfigError) as err:
        load_scenario(None, overrides)
    message = str(err.value)
    assert message.startswith(f"vehicle.physics_dt_s: got {physics_dt_s:g} with")
    assert f"episode.control_hz = {control_hz:g}" in message and "allowed:" in message
    # The substep the message offers, as printed, divides the period: the scenario takes it.
    offered = float(re.search(r"e\.g\. ([0-9.e+-]+) s\)", message).group(1))
    assert offered == pytest.approx(shorter, rel=1e-6)
    load_scenario(None, {**overrides, "vehicle": {"physics_dt_s": offered}})
