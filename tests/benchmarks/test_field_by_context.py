"""benchmarks/field_by_context.py: the inside volume and IoU of a field against the truth's."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import load_benchmark


def sphere_sdf(points: np.ndarray, radius: float) -> np.ndarray:
    return np.linalg.norm(points, axis=1) - radius


def test_a_field_too_big_reads_as_more_volume_and_less_iou():
    probe = load_benchmark("field_by_context")
    points = np.random.default_rng(0).uniform(-1, 1, (200_000, 3))
    truth = sphere_sdf(points, 0.5) < 0
    ratio, iou = probe.against_truth(sphere_sdf(points, 0.5), truth, 0.0, logits=False)
    assert ratio == 1.0 and iou == 1.0
    # a sphere of radius 0.6 around the truth's 0.5: (6/5)^3 the volume, IoU its inverse
    ratio, iou = probe.against_truth(sphere_sdf(points, 0.6), truth, 0.0, logits=False)
    assert ratio == pytest.approx(1.2**3, rel=0.02) and iou == pytest.approx(1 / 1.2**3, rel=0.02)
    # the same field as occupancy logits (positive inside): a level in probability picks the
    # surface, and level 0.5 (logit 0) is the sphere of radius 0.6 again
    logits = -sphere_sdf(points, 0.6) * 10
    assert probe.level_value(0.5, logits=True) == 0.0
    assert probe.against_truth(logits, truth, 0.0, logits=True) == (ratio, iou)
    # a lower probability level moves the surface out: the inside grows
    low = probe.level_value(0.2, logits=True)
    assert low == pytest.approx(math.log(0.25))
    assert probe.against_truth(logits, truth, low, logits=True)[0] > ratio


def test_a_level_outside_the_probabilities_is_refused_for_an_occupancy_field():
    probe = load_benchmark("field_by_context")
    with pytest.raises(SystemExit, match="not a probability"):
        probe.level_value(1.5, logits=True)
    assert probe.level_value(0.01, logits=False) == 0.01  # an SDF level is a field value
