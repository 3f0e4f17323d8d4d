import dataclasses
import math

import numpy as np
import pytest

from saddle_env import Scene


def test_defaults_are_the_papers_saddle():
    s = Scene()
    assert (s.a, s.b, s.g, s.alpha) == (0.159, 0.159, 9.8, 0.4)
    assert s.state_size == 5 and s.rolling


@pytest.mark.parametrize("kwargs, name", [
    ({"R": 0.0795}, "R"),            # = a/2
    ({"R": 0.08}, "R"),
    ({"R": 0.05, "b": 0.1}, "R"),    # = b/2
    ({"R": 0.0}, "R"),
    ({"R": -0.01}, "R"),
    ({"R": math.nan}, "R"),
    ({"a": 0.0}, "a"),
    ({"a": -1.0}, "a"),
    ({"a": math.inf}, "a"),
    ({"b": -0.1}, "b"),
    ({"b": math.nan}, "b"),
    ({"alpha": 0.0}, "alpha"),
    ({"alpha": 1.5}, "alpha"),
    ({"g": -9.8}, "g"),
    ({"g": math.inf}, "g"),
    ({"contact": "sliding"}, "contact"),
    ({"contact": 3}, "contact"),
    ({"rim_radius": 0.0}, "rim_radius"),
    ({"rim_radius": math.nan}, "rim_radius"),
    ({"rim_radius": "big"}, "rim_radius"),
    ({"drilling_friction": -1.0}, "drilling_friction"),
    ({"drag_linear": -0.1}, "drag_linear"),
    ({"drag_linear": math.inf}, "drag_linear"),
    ({"drag_quadratic": -1.0}, "drag_quadratic"),
    ({"drag_quadratic": math.nan}, "drag_quadratic"),
    ({"drag_quadratic": "0.1"}, "drag_quadratic"),
    ({"a": "0.159"}, "a"),
    ({"R": True}, "R"),
])
def test_invalid_parameters_name_themselves(kwargs, name):
    with pytest.raises(ValueError, match=rf"^{name} must"):
        Scene(**kwargs)


def test_error_gives_the_allowed_range():
    with pytest.raises(ValueError, match=r"0 < R < min\(a, b\)/2 = 0.0795"):
        Scene(R=0.1)


def test_point_ignores_radius_and_integrates_no_spin():
    s = Scene(contact="point", R=0.03)
    assert s.radius == 0.0 and s.state_size == 4
    assert s.params()[2] == 0.0
    assert Scene(contact="slipping").state_size == 4


def test_frozen_hashable_and_with():
    s = Scene()
    assert hash(s) == hash(Scene())
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.R = 0.01  # type: ignore[misc]
    assert s.with_(R=0.03).R == 0.03
    with pytest.raises(ValueError, match="unknown Scene parameter"):
        s.with_(radius=0.03)
    with pytest.raises(ValueError, match="^R must"):
        s.with_(R=1.0)


def test_numpy_scalars_accepted_and_normalised():
    s = Scene(a=np.float32(0.2), R=np.float64(0.01), rim_radius=math.inf)
    assert type(s.a) is float and s.rim_radius == math.inf
