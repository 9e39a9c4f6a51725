"""Settings: defaults from the paper, validation naming the field, replace()."""

from __future__ import annotations

import dataclasses
import math

import pytest

from core.errors import SettingsError
from core.settings import Settings


def test_defaults_follow_paper():
    s = Settings()
    assert s.mode == "bend"
    assert s.rotation_precision == 0.25
    assert s.max_angle == 180
    assert s.affected_connected_cvs == 2
    assert s.cv_falloff == 0.5
    assert s.attract_to_growth_surface is False
    assert s.shrink is False
    assert s.scale_minimum == 0.5
    assert s.scale_angle == 90
    assert s.recovery_rate == 0.2
    assert s.plasticity == 0
    assert s.pinch_resolution in ("stop", "growth_surface")
    assert s.recover_pinched is True
    assert s.collision_offset == 0
    assert s.threads is None


def test_frozen():
    s = Settings()
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.mode = "soft"


BAD = [
    ("mode", "wobbly"),
    ("mode", None),
    ("rotation_precision", 0.0),
    ("rotation_precision", -1.0),
    ("rotation_precision", math.nan),
    ("rotation_precision", "0.25"),
    ("max_angle", 0.0),
    ("max_angle", math.inf),
    ("max_angle", -5.0),
    ("affected_connected_cvs", -1),
    ("affected_connected_cvs", 1.5),
    ("affected_connected_cvs", True),
    ("cv_falloff", -0.1),
    ("cv_falloff", 1.1),
    ("cv_falloff", math.nan),
    ("attract_to_growth_surface", 1),
    ("attract_to_growth_surface", "yes"),
    ("shrink", None),
    ("scale_minimum", 0.0),
    ("scale_minimum", 1.5),
    ("scale_minimum", -0.2),
    ("scale_angle", 0.0),
    ("scale_angle", -10.0),
    ("recovery_rate", -0.01),
    ("recovery_rate", 1.01),
    ("recovery_rate", math.nan),
    ("plasticity", -0.5),
    ("plasticity", 2.0),
    ("pinch_resolution", "explode"),
    ("recover_pinched", 0),
    ("collision_offset", -1e-3),
    ("collision_offset", math.inf),
    ("collision_offset", math.nan),
    ("threads", 0),
    ("threads", -2),
    ("threads", 1.5),
    ("threads", True),
]


@pytest.mark.parametrize(("field", "value"), BAD, ids=[f"{f}={v!r}" for f, v in BAD])
def test_invalid_value_names_field(field, value):
    with pytest.raises(SettingsError) as ei:
        Settings(**{field: value})
    assert isinstance(ei.value, ValueError)
    assert f"Settings.{field}" in str(ei.value)
    # replace() validates too
    with pytest.raises(SettingsError) as ei2:
        Settings().replace(**{field: value})
    assert f"Settings.{field}" in str(ei2.value)


def test_recovery_rate_message_example():
    with pytest.raises(ValueError, match=r"Settings\.recovery_rate must be <= 1"):
        Settings(recovery_rate=1.5)


GOOD = [
    ("mode", "stiff"), ("mode", "bend"), ("mode", "soft"),
    ("rotation_precision", 0.01), ("rotation_precision", 5),
    ("max_angle", 90), ("max_angle", 360),
    ("affected_connected_cvs", 0), ("affected_connected_cvs", 10),
    ("cv_falloff", 0.0), ("cv_falloff", 1.0),
    ("attract_to_growth_surface", True), ("shrink", True),
    ("scale_minimum", 1.0), ("scale_minimum", 0.01), ("scale_angle", 1e-3),
    ("recovery_rate", 0.0), ("recovery_rate", 1.0),
    ("plasticity", 0.0), ("plasticity", 1.0),
    ("pinch_resolution", "stop"), ("pinch_resolution", "growth_surface"),
    ("recover_pinched", False), ("collision_offset", 0.0), ("collision_offset", 2.5),
    ("threads", 1), ("threads", 2), ("threads", None),
]


@pytest.mark.parametrize(("field", "value"), GOOD, ids=[f"{f}={v!r}" for f, v in GOOD])
def test_valid_values_accepted(field, value):
    s = Settings(**{field: value})
    assert getattr(s, field) == value


def test_replace_returns_new_copy_and_rejects_unknown():
    s = Settings()
    t = s.replace(mode="soft", shrink=True)
    assert (t.mode, t.shrink) == ("soft", True)
    assert (s.mode, s.shrink) == ("bend", False)
    with pytest.raises(SettingsError, match="no_such_field"):
        s.replace(no_such_field=1)


def test_max_angle_below_precision_rejected():
    with pytest.raises(SettingsError, match="max_angle"):
        Settings(rotation_precision=2.0, max_angle=1.0)


def test_to_dict_roundtrip():
    s = Settings(mode="soft", plasticity=0.3, threads=2)
    assert Settings(**s.to_dict()) == s
