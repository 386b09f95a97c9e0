"""Tracking with images (colour links, Eq. 14, Sec. 3.3.2 appearance) and resolution-free motion."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.datasets.box_scene import SceneConfig, simulate_box_scene
from xvmatch.datasets.tracking_video import render_tracking_video
from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.inference.linking.tracklets import clip_tracklets, split_clips, view_tracklets
from xvmatch.inference.matching.learned_association import load_matcher_bundle
from xvmatch.inference.tracks.track_appearance import (
    clip_appearance,
    colour_similarity,
    descriptor_similarity,
    frame_histograms,
)
from xvmatch.inference.tracks.track_costs import TrackWeights, motion_similarity, spatial_similarity
from xvmatch.inference.tracks.tracking import TrackConfig, TrackImages, _window_weights, track_pair


def _scaled(frames, s):
    return {f: FrameBoxes(f, r.ids, r.boxes * s) for f, r in frames.items()}


@pytest.fixture(scope="module")
def box_scene():
    return simulate_box_scene(SceneConfig(head_turn_std_deg=2.0, n_people=(4, 6)), n_frames=20,
                              seed=5)


@pytest.fixture(scope="module")
def box_tracks(box_scene):
    return track_pair(box_scene.top, box_scene.hor, float(box_scene.config.hor_size[0]))


@settings(max_examples=6, deadline=None)
@given(st.floats(0.25, 4.0), st.floats(0.25, 4.0))
def test_tracks_do_not_depend_on_the_image_size(box_scene, box_tracks, s_top, s_hor):
    # Every box of a view and its image size scaled: the same frame pairs and the same tracks.
    res = track_pair(_scaled(box_scene.top, s_top), _scaled(box_scene.hor, s_hor),
                     float(box_scene.config.hor_size[0]) * s_hor)
    assert res.frame_pairs == box_tracks.frame_pairs
    assert res.top_rows == box_tracks.top_rows and res.hor_rows == box_tracks.hor_rows


def test_without_images_the_weights_are_the_box_terms(box_scene, box_tracks):
    top, hor = box_scene.top, box_scene.hor
    clips = split_clips(sorted(top), 10)
    tt, ht = view_tracklets(top, clips), view_tracklets(hor, clips)
    w = TrackWeights()
    fp = box_tracks.frame_pairs
    got = _window_weights(tt[0], tt[1], ht[1], ht[0], fp, w)
    want = [motion_similarity(tt[0], tt[1], w.sigma), spatial_similarity(tt[1], ht[1], fp),
            motion_similarity(ht[0], ht[1], w.sigma).T, spatial_similarity(tt[0], ht[0], fp).T]
    for g, e in zip(got, want, strict=True):
        np.testing.assert_array_equal(g, e)
    # The image settings change nothing without images.
    other = TrackConfig(min_colour=0.9, time_appearance="colour",
                        weights=TrackWeights(w1=0.9, w2=0.1))
    res = track_pair(top, hor, float(box_scene.config.hor_size[0]), config=other,
                     frame_pairs=fp)
    assert res.top_rows == box_tracks.top_rows and res.hor_rows == box_tracks.hor_rows


def test_horizontal_links_need_colour_similarity():
    # Two people whose boxes (IoU 1/3 with each other) swap places every frame: IoU alone links
    # each box to the other person's, colour keeps each person on their own tracklet.
    a, b = [40.0, 20, 20, 40], [50.0, 20, 20, 40]
    frames, hist = {}, {}
    red, blue = np.eye(32)[0], np.eye(32)[5]
    for f in range(1, 5):
        frames[f] = FrameBoxes(f, np.array([2 * f, 2 * f + 1]),  # row 2f + k: person k
                               np.array([a, b] if f % 2 else [b, a]))
        hist[f] = np.array([red, blue])
    clip = np.arange(1, 5)
    by_iou = clip_tracklets(frames, clip, 0, min_iou=0.3)
    assert sorted(t.rows.tolist() for t in by_iou) == [[2, 5, 6, 9], [3, 4, 7, 8]]
    by_colour = clip_tracklets(frames, clip, 0, min_iou=0.3, histograms=hist)
    assert sorted(t.rows.tolist() for t in by_colour) == [[2, 4, 6, 8], [3, 5, 7, 9]]
    # A link still needs the IoU: far apart, the same colours make no tracklet.
    far = {f: FrameBoxes(f, r.ids, r.boxes + np.array([100.0 * f, 0, 0, 0]))
           for f, r in frames.items()}
    assert len(clip_tracklets(far, clip, 0, min_iou=0.3, histograms=hist)) == 8


def test_colour_appearance_is_eq14():
    # Boxes painted in one colour each on a grey image, apart from each other.
    frames, images = {}, {}
    colours = [(0, 0, 255), (255, 0, 0)]
    for f in range(1, 4):
        boxes = np.array([[10 + f, 20, 20, 40], [70 + f, 20, 20, 40]], dtype=float)
        image = np.full((100, 120, 3), 128, np.uint8)
        for (x, y, w, h), c in zip(boxes.astype(int), colours, strict=True):
            image[y:y + h, x:x + w] = c
        frames[f], images[f] = FrameBoxes(f, np.array([2 * f, 2 * f + 1]), boxes), image
    hist = frame_histograms(frames, images)
    tracklets = clip_tracklets(frames, np.arange(1, 4), 0, histograms=hist)
    assert sorted(t.rows.tolist() for t in tracklets) == [[2, 4, 6], [3, 5, 7]]
    app = clip_appearance(tracklets, frames, hist, images)
    assert app.descriptors is None
    # Histogram intersection of the median histograms: the same person 1, red against blue 0.
    np.testing.assert_allclose(colour_similarity(app, app), np.eye(2), atol=1e-12)


def test_network_appearance_of_tracklets():
    video = render_tracking_video(3, n_frames=6)
    model = load_matcher_bundle("default")
    clip = np.arange(1, 7)
    tracklets = clip_tracklets(video.top, clip, 0)
    hist = frame_histograms(video.top, video.top_images)
    app = clip_appearance(tracklets, video.top, hist, video.top_images, model.descriptors)
    assert app.descriptors.shape == (len(tracklets), 128)
    np.testing.assert_allclose(np.linalg.norm(app.descriptors, axis=1), 1.0, atol=1e-4)
    sim = descriptor_similarity(app, app)
    np.testing.assert_allclose(np.diag(sim), 1.0, atol=1e-3)  # float32 descriptors
    assert ((sim >= 0) & (sim <= 1 + 1e-9)).all()
    with pytest.raises(ValueError, match="needs descriptors"):
        descriptor_similarity(clip_appearance(tracklets, video.top, hist, video.top_images), app)
    # A site bundle's cross-view cost replaces |a - b| / 2 (xvmatch adapt); shape (M, N).
    calls = []

    def site_cost(a, b):
        calls.append((a.shape, b.shape))
        return np.full((a.shape[0], b.shape[0]), 0.25)

    np.testing.assert_array_equal(descriptor_similarity(app, app, site_cost),
                                  np.full((len(tracklets),) * 2, 0.75))
    assert calls == [((len(tracklets), 128), (len(tracklets), 128))]
    # A site adapted on the network's features: the cross-view cue takes those, the over-time
    # terms keep the descriptors; both come from one network run per frame.
    runs = []

    def one_run(image, boxes):
        runs.append(len(boxes))
        return tuple(model.bundle.embed_vectors(model.crops(image, boxes),
                                                ("descriptors", "features")))

    both = clip_appearance(tracklets, video.top, hist, video.top_images, model.descriptors,
                           one_run)
    middles = {int(t.frames[len(t) // 2]) for t in tracklets}
    assert len(runs) == len(middles) and sum(runs) == len(tracklets)
    np.testing.assert_allclose(both.descriptors, app.descriptors, atol=1e-6)
    assert both.cross.shape == (len(tracklets), 1280)
    calls.clear()
    descriptor_similarity(both, both, site_cost, cross=True)
    descriptor_similarity(both, both, site_cost)
    assert calls == [((len(tracklets), 1280),) * 2, ((len(tracklets), 128),) * 2]


def _as_rows(frames):
    """Ids -> row numbers unique over the view (what ``track_pair`` takes); ``{row: id}``."""
    out, truth, row = {}, {}, 0
    for f in sorted(frames):
        rec = frames[f]
        rows = np.arange(row, row + len(rec))
        truth.update(zip(rows.tolist(), rec.ids.tolist(), strict=True))
        out[f] = FrameBoxes(f, rows, rec.boxes)
        row += len(rec)
    return out, truth


@pytest.mark.slow
@pytest.mark.parametrize("network", [False, True])
def test_track_pair_with_images_on_a_rendered_clip(network):
    video = render_tracking_video(1, n_frames=30)
    top, top_truth = _as_rows(video.top)
    hor, hor_truth = _as_rows(video.hor)
    embed = load_matcher_bundle("default").descriptors if network else None
    images = TrackImages(video.top_images, video.hor_images, embed)
    res = track_pair(top, hor, float(video.hor_size[0]), images=images)
    assert set(res.top_rows) == set(top_truth) and set(res.hor_rows) == set(hor_truth)
    good = bad = 0  # cross-view pairs (same track id in a frame), right or wrong
    for f in top:
        by_id = {res.top_rows[r]: top_truth[r] for r in top[f].ids.tolist()}
        for r in hor[f].ids.tolist():
            person = by_id.get(res.hor_rows[r])
            if person is not None:
                good += person == hor_truth[r]
                bad += person != hor_truth[r]
    assert good > 3 * bad and good > 0, (good, bad)


@pytest.mark.slow
def test_top_images_are_read_only_where_needed():
    # With the network over time the top view needs no histogram and only its tracklets'
    # middle frames: the same tracklets and descriptors as when every frame is read.
    from xvmatch.inference.tracks.tracking import _tracklets_with_images

    video = render_tracking_video(4, n_frames=12)
    top, _ = _as_rows(video.top)
    hor, _ = _as_rows(video.hor)
    embed = load_matcher_bundle("default").descriptors
    clips = split_clips(sorted(top), 6)

    class Counted(dict):
        def get(self, frame):
            self.read = getattr(self, "read", 0) + 1
            return self[frame]

    results = {}
    for mode in ("colour", "network"):
        source = Counted(video.top_images)
        images = TrackImages(source, video.hor_images, embed)
        results[mode] = (*_tracklets_with_images(top, hor, clips, TrackConfig(
            time_appearance=mode), images, None), source.read)
    (t_c, h_c, a_c, read_c), (t_n, h_n, a_n, read_n) = results["colour"], results["network"]
    assert read_c == 12 and read_n < read_c
    for k in range(len(clips)):
        assert [t.rows.tolist() for t in t_c[k]] == [t.rows.tolist() for t in t_n[k]]
        assert [t.rows.tolist() for t in h_c[k]] == [t.rows.tolist() for t in h_n[k]]
        np.testing.assert_array_equal(a_c[k][0].descriptors, a_n[k][0].descriptors)
        assert a_n[k][0].histograms.shape[1] == 0
        with pytest.raises(ValueError, match="needs histograms"):
            colour_similarity(a_n[k][0], a_n[k][0])
