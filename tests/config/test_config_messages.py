"""Numbers in settings errors: short (``1e+300``), never hundreds of digits, and an integer too
large for a float is a ``ConfigError`` like any other out-of-range value."""

from __future__ import annotations

import re
from typing import Any

import pytest

from quadslam_env.config.scenario import load_scenario
from quadslam_env.schema import ConfigError, shown_value


@pytest.mark.parametrize(
    ("value", "text"),
    [
        (10**300, "1e+300"),
        (-(10**400), "-1e+400"),  # beyond any float
        (3 * 10**5000, "3e+5000"),  # beyond int's own str() limit
        (12345678901234567890, "1.23457e+19"),
        (1234567890123456, "1234567890123456"),  # 16 digits: as written
        (1e300, "1e+300"),
        (0.1, "0.1"),
        (True, "True"),
        ([10**30, 1.5, "a"], "[1e+30, 1.5, 'a']"),
        ((10**30,), "(1e+30,)"),
        ((1.0, 2.0), "(1.0, 2.0)"),
        ("x", "'x'"),
        (None, "None"),
    ],
    ids=lambda v: v if isinstance(v, str) else type(v).__name__,  # str(3e5000) would fail
)
def test_values_are_shown_short(value: Any, text: str) -> None:
    assert shown_value(value) == text


def test_a_long_value_is_cut_to_200_characters() -> None:
    text = shown_value("y" * 1000)
    assert len(text) == 200 and text.startswith("'yyy") and text.endswith("...")


@pytest.mark.parametrize(
    "overrides",
    [
        {"vehicle": {"mass_kg": 1e300}},  # the weight m g in the hover check
        {"vehicle": {"mass_kg": 10**300}},
        {"vehicle": {"preset": "crazyflie2", "mass_kg": 1e300}},  # the rotors' hover speed
        {"vehicle": {"max_thrust_n": 10**300, "mass_kg": 10**301}},  # cannot hover
        {"vehicle": {"max_torque_nm": [-(10**300), 1.0, 1.0]}},
        {"episode": {"duration_s": 10**400}},  # no float holds it
        {"episode": {"duration_s": [10**400]}},
    ],
)
def test_huge_settings_give_a_short_config_error(overrides: dict[str, Any]) -> None:
    with pytest.raises(ConfigError) as err:
        load_scenario(None, overrides)
    message = str(err.value)
    assert re.search(r"\d{20}", message) is None, message[:300]
    assert len(message) < 400 and len(message.splitlines()) == 1
    assert re.search(r"e\+(300|301|400)", message), message
