"""The simulated camera change: seeded, bounded, one camera per view when asked."""

import numpy as np
import pytest

from xvmatch.datasets.camera_shift import MAX_STRENGTH, camera_shift


def _flat(value: int, marker: int = 0) -> np.ndarray:
    image = np.full((48, 32, 3), value, np.uint8)
    image[0, 0] = marker  # a different picture of the same scene
    return image


def test_strength_zero_is_identity_and_draws_are_seeded():
    image = np.random.default_rng(0).integers(0, 256, (40, 30, 3), dtype=np.uint8)
    assert np.array_equal(camera_shift(image, 0.0), image)
    for s in (0.5, 1.0, MAX_STRENGTH):
        a, b = camera_shift(image, s, seed=3), camera_shift(image, s, seed=3)
        assert np.array_equal(a, b) and a.shape == image.shape and a.dtype == np.uint8


@pytest.mark.parametrize("bad", [-0.1, MAX_STRENGTH + 0.01, float("nan")])
def test_strength_out_of_range_is_refused(bad):
    with pytest.raises(ValueError, match="strength"):
        camera_shift(_flat(100), bad)


def test_one_camera_per_view_keeps_its_colour_cast_across_frames():
    frames = [_flat(120, m) for m in range(6)]
    fixed = np.array([camera_shift(f, 1.5, seed=7, per_image=False)[20:28, 12:20].mean((0, 1))
                      for f in frames])
    drawn = np.array([camera_shift(f, 1.5, seed=7)[20:28, 12:20].mean((0, 1)) for f in frames])
    assert np.ptp(fixed, axis=0).max() < 6.0  # same camera: only the sensor noise differs
    assert np.ptp(drawn, axis=0).max() > 15.0  # a new camera per image
