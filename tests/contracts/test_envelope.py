import pytest
from pydantic import ValidationError

from contracts.envelope import Envelope


def test_envelope_of_a_grid_starts_at_rest():
    env = Envelope.of_grid([0.25, 0.5, 10.0], [-10.0, 0.0, 10.0])
    assert env.displacement_mm == (0.0, 10.0) and env.angle_deg == (-10.0, 10.0)
    assert env.contains(0.0, -10.0) and env.contains(10.0, 10.0)
    assert not env.contains(10.01, 0.0) and not env.contains(5.0, -10.5)


def test_samples_are_inside_reproducible_and_above_the_floor():
    env = Envelope(displacement_mm=(0.0, 10.0), angle_deg=(-10.0, 10.0))
    cases = env.sample(200, seed=0, min_displacement_mm=0.25)
    assert cases == env.sample(200, seed=0, min_displacement_mm=0.25)
    assert cases != env.sample(200, seed=1, min_displacement_mm=0.25)
    assert all(0.25 <= d <= 10.0 and env.contains(d, a) for d, a in cases)


def test_reversed_bounds_are_refused():
    with pytest.raises(ValidationError, match="lower bound"):
        Envelope(displacement_mm=(5.0, 1.0), angle_deg=(0.0, 1.0))
