"""The same scene at another image resolution gives the same matches (features version 2).

Each view's boxes, and the horizontal image size, scaled by any factor in [0.25, 4] (the same
videos exported at another resolution): the handcrafted search picks the same pairs, the learned
features are the same, and the learned matcher picks the same pairs.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.cues.spatial_features import FeatureConfig, frame_features
from xvmatch.cues.spatial_search import associate_frame, associate_sequence
from xvmatch.datasets.box_scene import SceneConfig, simulate_box_scene
from xvmatch.formats.mot_boxes import scale_frames
from xvmatch.inference.matching.learned_association import (
    associate_sequence_learned,
    load_matcher_bundle,
)

SIZE = (2688, 1512)
SCENE = simulate_box_scene(SceneConfig(n_people=(6, 10)), n_frames=12, seed=3)
FRAMES = [f for f in sorted(SCENE.top) if len(SCENE.top[f]) and len(SCENE.hor[f])]
factors = st.floats(0.25, 4.0, allow_nan=False)


@settings(max_examples=12, deadline=None)
@given(top_factor=factors, hor_factor=factors, k=st.integers(0, len(FRAMES) - 1))
def test_handcrafted_search_is_resolution_free(top_factor, hor_factor, k):
    f = FRAMES[k]
    base = associate_frame(SCENE.top[f].boxes, SCENE.hor[f].boxes, SIZE[0])
    scaled = associate_frame(SCENE.top[f].boxes * top_factor, SCENE.hor[f].boxes * hor_factor,
                             SIZE[0] * hor_factor)
    assert scaled.camera == base.camera and scaled.theta == pytest.approx(base.theta)
    np.testing.assert_array_equal(scaled.pairs, base.pairs)
    assert scaled.cost == pytest.approx(base.cost, rel=1e-9)


@settings(max_examples=12, deadline=None)
@given(top_factor=factors, hor_factor=factors, k=st.integers(0, len(FRAMES) - 1))
def test_learned_features_are_resolution_free(top_factor, hor_factor, k):
    f = FRAMES[k]
    config = FeatureConfig(n_hypotheses=4, dtheta_deg=2.0)
    base = frame_features(SCENE.top[f].boxes, SCENE.hor[f].boxes, SIZE, config)
    scaled = frame_features(SCENE.top[f].boxes * top_factor, SCENE.hor[f].boxes * hor_factor,
                            (SIZE[0] * hor_factor, SIZE[1] * hor_factor), config)
    for name in ("top", "hor", "hyp", "pair"):
        np.testing.assert_allclose(getattr(scaled, name), getattr(base, name), rtol=1e-4,
                                   atol=1e-4, err_msg=name)
    np.testing.assert_array_equal(scaled.top_order, base.top_order)
    np.testing.assert_array_equal(scaled.hor_order, base.hor_order)


def test_border_margin_and_reference_y_scale_with_the_image():
    """A box touching the right border is flagged at any resolution; y_hor is in pixels of a
    2688-wide image (the paper's lambda keeps its meaning)."""
    from xvmatch.cues.spatial_features import HOR_FEATURES
    from xvmatch.cues.spatial_vectors import horizontal_vectors

    boxes = np.array([[2600.0, 500.0, 87.0, 400.0], [1000.0, 500.0, 100.0, 400.0]])
    top = np.array([[100.0, 100.0, 20.0, 20.0], [300.0, 100.0, 20.0, 20.0]])
    col = HOR_FEATURES.index("at_border")
    for factor in (0.25, 1.0, 3.0):
        feats = frame_features(top, boxes * factor, (SIZE[0] * factor, SIZE[1] * factor),
                               FeatureConfig(n_hypotheses=2))
        flags = feats.hor[np.argsort(feats.hor_order), col]
        assert flags.tolist() == [1.0, 0.0]
        vectors, _ = horizontal_vectors(boxes * factor, SIZE[0] * factor)
        np.testing.assert_allclose(np.sort(vectors[:, 1]), [1 / 400, 1 / 400])


@pytest.mark.parametrize("factor", [0.5, 2.0])
def test_sequences_match_the_same_at_half_and_twice_the_resolution(factor, tiny_models):
    """Whole sequences, both methods: the same pairs on every frame."""
    top, hor = scale_frames(SCENE.top, factor), scale_frames(SCENE.hor, factor)
    hand = associate_sequence(SCENE.top, SCENE.hor, SIZE[0])
    assert associate_sequence(top, hor, SIZE[0] * factor) == hand
    model = load_matcher_bundle(tiny_models["boxes_bundle"])
    learned = associate_sequence_learned(SCENE.top, SCENE.hor, SIZE[0], model, gamma=1.0,
                                         hor_height=SIZE[1])
    assert sum(len(p) for p in learned.values()) > 0
    assert associate_sequence_learned(top, hor, SIZE[0] * factor, model, gamma=1.0,
                                      hor_height=SIZE[1] * factor) == learned
