"""The live rest detector: when it says "not at rest", the runner's refusal says why."""

from __future__ import annotations

from thrustmap.rig.interfaces import StandSample
from thrustmap.rig.settle import RestDetector


def feed(det: RestDetector, samples: list[StandSample]) -> bool:
    return any([det.update(s.time_s, [s]) for s in samples])


def test_at_rest_on_a_still_load_cell() -> None:
    det = RestDetector(1.0)
    assert feed(det, [StandSample(0.02 * k, 0.001 * (k % 2)) for k in range(60)])


def test_a_coasting_rotor_is_named_by_its_rpm() -> None:
    det = RestDetector(1.0)
    assert not feed(det, [StandSample(0.02 * k, 0.0, rpm=900.0) for k in range(60)])
    assert det.why_not == "the stand reads 900 rpm"


def test_a_moving_thrust_is_named_with_its_range() -> None:
    det = RestDetector(1.0)
    assert not feed(det, [StandSample(0.02 * k, 0.5 - 0.01 * k) for k in range(60)])
    assert det.why_not.startswith("thrust still moving (")


def test_too_few_readings_says_how_many() -> None:
    det = RestDetector(1.0)
    assert not feed(det, [StandSample(0.5 * k, 0.0) for k in range(10)])
    assert det.why_not.startswith("3 stand readings over 1.00 s in the last 1 s")
