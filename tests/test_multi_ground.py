"""``associate-multi`` with an oblique top camera (issue 67, item 5): the top view calibrated
from its people once, each handheld view registered on its ground map, the views joined there by
the cycle-consistent program; on a rendered scene with two handheld cameras, ids scrambled per
view, against ``associate --top-view oblique``'s run per handheld view."""

from __future__ import annotations

from itertools import combinations

import numpy as np
import pytest

from xvmatch.cli import main
from xvmatch.datasets.oblique_scenes import ObliqueSceneConfig, make_oblique_scene
from xvmatch.formats.mot_boxes import FrameBoxes, read_mot_boxes, write_mot_boxes
from xvmatch.geometry.people_calibration import measure_spread
from xvmatch.inference.matching.frame_rate import READ_RATE_SLACK, frame_rate_note
from xvmatch.inference.matching.ground_association import (
    GroundAssociationOptions,
    run_ground_association,
    top_calibration,
)
from xvmatch.inference.views.multi_ground import (
    REGISTERED,
    MultiGroundOptions,
    ground_problems,
    oblique_top,
    top_map,
)

SIZE = (1920, 1080)


def _scrambled(frames: dict, offset: int) -> tuple[dict, dict]:
    """The view with its ids replaced (a fixed permutation per view), and the way back."""
    ids = sorted({int(i) for r in frames.values() for i in r.ids})
    new = {i: offset + (7 * k) % len(ids) for k, i in enumerate(ids)}
    return ({f: FrameBoxes(f, np.array([new[int(i)] for i in r.ids], dtype=np.int64), r.boxes)
             for f, r in frames.items()}, {v: k for k, v in new.items()})


@pytest.fixture(scope="module")
def scene():
    config = ObliqueSceneConfig(n_hor=2, top_pitch=(25.0, 45.0), overlap=(0.5, 1.0),
                                hor_sizes=(SIZE,))
    sc = make_oblique_scene(config, 60, np.random.default_rng(3))
    keep = [f for f in sorted(sc.top) if f % 3 == 1]  # every 3rd frame, 3.3 a second
    views, backs = zip(*(_scrambled({f: v[f] for f in keep if f in v}, 100 * (k + 1))
                         for k, v in enumerate([sc.top, sc.hor["hor1"], sc.hor["hor2"]])),
                       strict=True)
    return list(views), list(backs)


def _truth(views, backs) -> dict:
    return {(a, b): {(f, int(i), int(j)) for f in views[a] if f in views[b]
                     for i in views[a][f].ids for j in views[b][f].ids
                     if backs[a][int(i)] == backs[b][int(j)]}
            for a, b in combinations(range(len(views)), 2)}


def _f1(pred: set, truth: set) -> float:
    return 2 * len(pred & truth) / max(1, len(pred) + len(truth))


@pytest.mark.slow
def test_three_views_pair_at_least_as_well_as_per_view(scene, tmp_path, capsys) -> None:
    views, backs = scene
    paths = []
    for name, v in zip(("top", "hor1", "hor2"), views, strict=True):
        paths.append(tmp_path / f"{name}.txt")
        write_mot_boxes(paths[-1], v)
    out = tmp_path / "out"
    assert main(["associate-multi", "--top", str(paths[0]), "--hor", str(paths[1]),
                 str(paths[2]), "--out", str(out), "--top-image-size", "1920x1080",
                 "--image-size", "1920x1080", "--fps", "3.33", "--quiet"]) == 0
    # The output rows are the input rows, in order, with a person id in the id field.
    person = []
    for name, v in zip(("top", "hor1", "hor2"), views, strict=True):
        got = read_mot_boxes(out / f"{name}.txt")
        person.append({(f, int(i)): int(p) for f in v
                       for i, p in zip(v[f].ids, got[f].ids, strict=True)})
    truth = _truth(views, backs)
    multi = {ab: {(f, i, j) for (f, i), p in person[ab[0]].items()
                  for (g, j), q in person[ab[1]].items() if f == g and p == q}
             for ab in truth}
    # associate --top-view oblique per handheld view (each frame on its own), the handheld
    # pairs joined through the top view.
    calib = top_calibration(views[0], SIZE)
    per_view = {(0, k): {(f, a, b) for f, p in run_ground_association(
        views[0], views[k], GroundAssociationOptions(SIZE, SIZE, fps=3.33, consensus=False),
        calibration=calib).pairs.items() for a, b in p} for k in (1, 2)}
    per_view[(1, 2)] = {(f, i, j) for f, t, i in per_view[(0, 1)]
                        for g, u, j in per_view[(0, 2)] if f == g and t == u}
    f1 = {name: {ab: _f1(pred[ab], truth[ab]) for ab in truth}
          for name, pred in (("multi", multi), ("per view", per_view))}
    pooled = {name: _f1(set().union(*({(ab, *x) for x in pred[ab]} for ab in truth)),
                        set().union(*({(ab, *x) for x in truth[ab]} for ab in truth)))
              for name, pred in (("multi", multi), ("per view", per_view))}
    # Measured: pooled pair F1 0.628 (three views) against 0.594 (per view); top-hor1 0.720
    # against 0.722, top-hor2 0.607 against 0.506, hor1-hor2 0.533 against 0.550.
    assert pooled["multi"] >= pooled["per view"]
    assert pooled["multi"] > 0.55
    assert min(f1["multi"].values()) > 0.45
    # Each handheld view's candidate lenses run side by side: the same output. The steady top
    # camera is said in one line, once its tilt is read: its tilt, with its spread.
    side = tmp_path / "side"
    capsys.readouterr()
    assert main(["associate-multi", "--top", str(paths[0]), "--hor", str(paths[1]),
                 str(paths[2]), "--out", str(side), "--top-image-size", "1920x1080",
                 "--image-size", "1920x1080", "--fps", "3.33", "--workers", "2"]) == 0
    for name in ("top", "hor1", "hor2"):
        assert (side / f"{name}.txt").read_bytes() == (out / f"{name}.txt").read_bytes()
    said = [line for line in capsys.readouterr().err.splitlines() if "note: top view" in line]
    assert len(said) == 1 and "note: top view: oblique, tilt " in said[0], said
    assert " +- " in said[0] and said[0].endswith(REGISTERED)


@pytest.mark.slow
def test_oblique_top_decides_and_refuses(scene) -> None:
    views, _ = scene
    calib, note = oblique_top(views[0], "auto", SIZE, "top.txt", [0, 0])
    assert calib is not None and calib.kind == "oblique" and note is None  # said by the run
    assert oblique_top(views[0], "nadir", SIZE, "top.txt") == (None, None)
    # Without its size, the upright people's top view takes the smallest common video size
    # holding its boxes, and says so; a forced kind without a size is the command's refusal.
    calib, note = oblique_top(views[0], "auto", None, "top.txt")
    assert calib is not None and calib.kind == "oblique"
    assert note.startswith("top view: its size taken as") and "--top-image-size" in note
    assert oblique_top(views[0], "oblique", None, "top.txt") == (None, None)
    far = {1: FrameBoxes(1, [1], [[9000.0, 10.0, 20.0, 50.0]])}
    calib, note = oblique_top(far, "auto", None, "top.txt")
    assert calib is None and "no common video size holds" in note
    few = {1: FrameBoxes(1, [1, 2], [[100.0, 100.0, 20.0, 50.0], [300.0, 120.0, 20.0, 50.0]])}
    calib, note = oblique_top(few, "auto", None, "top.txt")  # too few: the nadir path, said
    assert calib is None and "cannot be calibrated from its people" in note
    with pytest.raises(ValueError, match="the calibration needs"):  # a size given: an error
        oblique_top(few, "auto", (640, 360), "top.txt")
    with pytest.raises(ValueError, match="--offset auto"):
        oblique_top(views[0], "oblique", SIZE, "top.txt", ["auto", 0])
    with pytest.raises(ValueError, match=r"top\.txt.*--top-image-size"):
        oblique_top(views[0], "oblique", (640, 360), "top.txt")
    with pytest.raises(ValueError, match="top_view"):
        oblique_top(views[0], "sideways", SIZE, "top.txt")


def test_oblique_top_follows_the_top_views_tracks_in_video_mode(scene) -> None:
    """associate-multi reads its boxes by row (each row its own id); in video mode the top
    view's tracks give each followed person a height of their own in the calibration, as
    associate's calibration from the same file, and in frame mode the boxes linked by IoU
    (the file's ids unread), as associate's in frame mode."""
    views, _ = scene
    rows = {f: FrameBoxes(f, 1000 * f + np.arange(len(r.ids)), r.boxes)
            for f, r in views[0].items()}
    tracks = {1000 * f + n: int(i) for f, r in views[0].items() for n, i in enumerate(r.ids)}
    video, _ = oblique_top(rows, "oblique", SIZE, "top.txt", top_tracks=tracks)
    frame, _ = oblique_top(rows, "oblique", SIZE, "top.txt")
    video, frame = measure_spread(video), measure_spread(frame)  # its spread left for later
    assert video == top_calibration(views[0], SIZE)
    assert frame == top_calibration(views[0], SIZE, tracks=False) and frame != video


@pytest.mark.slow
def test_problems_shapes_and_no_evidence_off_the_map(scene) -> None:
    views, _ = scene
    calib = top_calibration(views[0], SIZE)
    frames = sorted(set().union(*views))
    problems = ground_problems(views, frames, calib, MultiGroundOptions((SIZE, SIZE), fps=3.33))
    for f in frames:
        pr = problems[f]
        assert pr.sizes == tuple(len(v[f].ids) if f in v else 0 for v in views)
        for (a, b), c in pr.costs.items():
            assert c.shape == (pr.sizes[a], pr.sizes[b]) and np.isfinite(c).all()
        assert set(pr.gamma.values()) <= {0.0}
    empty = [{}, *views[1:]]  # no top view: no registration, no pair worth making
    none = ground_problems(empty, frames, calib, MultiGroundOptions((SIZE, SIZE), fps=3.33))
    assert all((c > 0).all() for pr in none.values() for c in pr.costs.values())
    with pytest.raises(ValueError, match="hor_sizes"):
        ground_problems(views, frames, calib, MultiGroundOptions((SIZE,)))


@pytest.mark.slow
def test_fps_auto_reads_the_top_views_walkers_by_its_tracks(scene, registration_paces) -> None:
    """associate-multi's ``--fps auto``: the top view's people followed by its tracks (its ids
    are its rows) give the rate :func:`top_frame_rate` reads from the file's own ids, said in
    one note, and the run is the one told that rate and the looser walk a rate read gets."""
    from xvmatch.inference.matching.ground_association import top_frame_rate
    from xvmatch.inference.views.multi_ground import run_multi_ground
    from xvmatch.inference.views.multi_view_people import PeopleOptions

    views, _ = scene
    rows = [{f: FrameBoxes(f, 1000 * f + np.arange(len(r.ids)), r.boxes) for f, r in v.items()}
            for v in views]
    tracks = [{1000 * f + n: int(i) for f, r in v.items() for n, i in enumerate(r.ids)}
              for v in views]
    calib = top_calibration(views[0], SIZE)
    said: list[str] = []
    auto = run_multi_ground(rows, [0, 0], calib, MultiGroundOptions((SIZE, SIZE), 70.0, "auto"),
                            PeopleOptions(), tracks, said.append)
    rate = top_frame_rate(views[0], calib)
    assert [s for s in said if s.startswith("frame numbers")] == [frame_rate_note(rate)]
    assert rate.estimated and set(registration_paces) == {(rate.fps, READ_RATE_SLACK)}
    told = run_multi_ground(rows, [0, 0], calib,
                            MultiGroundOptions((SIZE, SIZE), 70.0, rate.fps, rate.slack),
                            PeopleOptions(), tracks, said.append)
    assert auto == told
    with pytest.raises(ValueError, match="fps must be frames a second or 'auto'"):
        MultiGroundOptions((SIZE, SIZE), 70.0, "fast")
    with pytest.raises(ValueError, match="slack must be positive"):
        MultiGroundOptions((SIZE, SIZE), 70.0, 3.0, 0.0)
    with pytest.raises(ValueError, match="lens_slack must be positive or None"):
        MultiGroundOptions((SIZE, SIZE), 70.0, 3.0, 1.0, lens_slack=0.0)


def test_ground_options_guess_only_a_size_assumed() -> None:
    """associate-multi's ground path takes a handheld size assumed to be CVMHAT's from its boxes
    (the smallest common video size holding them), saying so; a size given stays."""
    from xvmatch.formats.box_image_size import ASSUMED, CVMHAT_SIZE
    from xvmatch.inference.views.multi_ground import ground_options

    phone = {1: FrameBoxes(1, np.array([1]), np.array([[1700.0, 600.0, 60.0, 170.0]]))}
    views = [{}, phone, phone]
    said: list[str] = []
    options = ground_options(views, [(CVMHAT_SIZE, ASSUMED), ((1920, 1080), "--image-size")],
                             ["top.txt", "hor1.txt", "hor2.txt"], "auto", "auto", said.append)
    assert options.hor_sizes == ((1920, 1080), (1920, 1080))
    assert (options.hor_hfov_deg, options.fps) == ("auto", "auto")
    assert said == ["hor1.txt: its images taken as 1920x1080 on this path, the smallest common "
                    "video size holding its boxes, not CVMHAT's (give --image-size WxH if not)"]
    # Boxes that fit CVMHAT's own size (no smaller common size holds them): kept, said.
    wide = {1: FrameBoxes(1, np.array([1]), np.array([[2500.0, 1200.0, 100.0, 300.0]]))}
    said.clear()
    options = ground_options([{}, wide], [(CVMHAT_SIZE, ASSUMED)], ["top.txt", "hor1.txt"],
                             "auto", "auto", said.append)
    assert options.hor_sizes == (CVMHAT_SIZE,)
    assert said == ["assuming hor1.txt's images are 2688x1512 (CVMHAT; its boxes reach x 2600, "
                    "y 1500); pass --image-size WxH if not"]


def test_a_size_not_known_is_guessed_on_the_ground_path_only() -> None:
    """associate-multi: a handheld view whose boxes do not fit CVMHAT's size (no size given)
    takes the guess on the ground-map path, saying so; the nadir path refuses it, naming it."""
    from xvmatch.formats.box_image_size import UNKNOWN
    from xvmatch.inference.views.multi_ego_run import path_sizes
    from xvmatch.inference.views.multi_ground import ground_options

    big = {1: FrameBoxes(1, np.array([1]), np.array([[3500.0, 1500.0, 120.0, 500.0]]))}
    views, paths = [{}, big], ["top.txt", "hor1.txt"]
    resolved = [((3840, 2160), UNKNOWN)]
    assert path_sizes(resolved, views, paths, ground=True) == [(3840, 2160)]
    with pytest.raises(ValueError, match=r"^hor1\.txt: the horizontal image size is unknown"):
        path_sizes(resolved, views, paths, ground=False)
    said: list[str] = []
    options = ground_options(views, resolved, paths, "auto", "auto", said.append)
    assert options.hor_sizes == ((3840, 2160),)
    assert said == ["hor1.txt: its images taken as 3840x2160 on this path, the smallest common "
                    "video size holding its boxes (give --image-size WxH if not)"]


def test_a_tall_person_cut_by_the_drones_near_edge_stands_where_associate_puts_them(
        close_drone) -> None:
    """associate-multi's top map (:func:`top_map`): a tall person walking out of a close drone's
    bottom edge is placed, once cut, where the ray through their box's top meets the plane of
    their own height, read from their whole boxes along their track (video mode) or their boxes
    linked by IoU (frame mode), as associate places them; at the crowd's height they were put
    too near (the old map)."""
    from xvmatch.datasets.oblique_scenes import project_view
    from xvmatch.geometry.people_calibration import cut_at_bottom

    calib = close_drone
    edge = calib.ground_points(np.array([[SIZE[0] / 2, SIZE[1] - 1.0]]))[0]
    heights = np.array([1.9, calib.person_height, calib.person_height])
    top, tracks, truth = {}, {}, {}
    for f in range(1, 9):  # the tall one walks out of the image's bottom edge
        where = np.array([[edge[0] + 2.2 - 0.4 * f, edge[1]], [edge[0] + 6.0, edge[1] + 3.0],
                          [edge[0] + 8.0, edge[1] - 3.0]])
        index, boxes = project_view(where, heights, np.full(3, 0.45), calib.camera)
        assert list(index) == [0, 1, 2]
        top[f] = FrameBoxes(f, 10 * f + np.arange(3), boxes)
        tracks.update({10 * f + k: k for k in range(3)})
        truth[f] = where[0]
    assert cut_at_bottom(top[8].boxes, SIZE[1]).tolist() == [True, False, False]
    assert not cut_at_bottom(top[1].boxes, SIZE[1]).any()
    for top_tracks in (tracks, None):
        placed = top_map([top], range(1, 9), calib, top_tracks)
        assert placed.sizes[8][0] == pytest.approx(1.9 / calib.person_height, abs=0.01)
        assert np.hypot(*(placed.points[8][0] - truth[8])) < 0.35
    crowd = calib.standing_points(top[8].boxes)[0]  # everyone at the crowd's height
    assert np.hypot(*(crowd - truth[8])) > 0.35



@pytest.mark.slow
def test_a_top_map_off_in_scale_pairs_as_the_right_one_in_video_mode(scene):
    """The top map shrunk or stretched by 1.3 (its camera's height read 30 % off): in video
    mode each handheld view keeps the map scale whose run keeps the most pairs along both
    views' tracks, as ``associate`` does, and the three views pair as on the right map."""
    from xvmatch.inference.views.multi_ego_video import video_people
    from xvmatch.inference.views.multi_ground import VIDEO_KEEP_FREE, TopMap
    from xvmatch.inference.views.multi_view_people import PeopleOptions

    views, _ = scene
    rows = [{f: FrameBoxes(f, 1000 * f + np.arange(len(r.ids)), r.boxes) for f, r in v.items()}
            for v in views]
    tracks = [{1000 * f + n: int(i) for f, r in v.items() for n, i in enumerate(r.ids)}
              for v in views]
    frames = sorted(set().union(*rows))
    calib = top_calibration(views[0], SIZE)
    tops = top_map(rows, frames, calib, tracks[0])
    options = MultiGroundOptions((SIZE, SIZE), 70.0, 3.33)

    def people(top: TopMap):
        problems = ground_problems(rows, frames, calib, options, tracks, top)
        return video_people(rows, problems, frames, tracks, PeopleOptions(), VIDEO_KEEP_FREE)

    right = people(tops)
    for off in (1.3, 0.7):
        assert people(TopMap({f: p / off for f, p in tops.points.items()}, tops.sizes,
                             tops.walkers)) == right


@pytest.mark.slow
def test_the_holders_ids_place_each_handheld_camera(scene) -> None:
    """``associate-multi --camera-id``: each holder pairs with nobody of their own view; in
    video mode each handheld camera is sought near where the top view maps its holder where
    that keeps more pairs along the tracks, frame by frame anywhere; the pairs hold as well as
    without, and one note says what was done per view."""
    from xvmatch.inference.views.multi_ground import run_multi_ground
    from xvmatch.inference.views.multi_view_people import PeopleOptions

    views, backs = scene
    config = ObliqueSceneConfig(n_hor=2, top_pitch=(25.0, 45.0), overlap=(0.5, 1.0),
                                hor_sizes=(SIZE,))
    holders = make_oblique_scene(config, 60, np.random.default_rng(3)).groups["holders"]
    ids = [next(a for a, b in backs[0].items() if b == int(h)) for h in holders]
    wearers = tuple({f: int(np.flatnonzero(r.ids == i)[0]) for f, r in views[0].items()
                     if i in r.ids} for i in ids)
    assert all(wearers)  # the drone sees both holders here
    calib = top_calibration(views[0], SIZE)
    rows = [{f: FrameBoxes(f, 1000 * f + np.arange(len(r.ids)), r.boxes) for f, r in v.items()}
            for v in views]  # as associate-multi reads them: each row its own id
    tracks = [{1000 * f + n: int(i) for f, r in v.items() for n, i in enumerate(r.ids)}
              for v in views]
    truth = _truth(views, backs)
    for video in (False, True):
        said: list[str] = []
        f1 = []
        for w in (None, wearers):
            run = run_multi_ground(rows, [0, 0], calib, MultiGroundOptions(
                (SIZE, SIZE), 70.0, 3.33, wearers=w), PeopleOptions(),
                tracks if video else None, said.append)
            person = [{(f, int(i)): run.people.person[k].get(1000 * f + n, -1) for f in v
                       for n, i in enumerate(v[f].ids)} for k, v in enumerate(views)]
            pred = {(a, b): {(f, i, j) for (f, i), p in person[a].items()
                             for (g, j), q in person[b].items() if f == g and p == q and p >= 0}
                    for a, b in truth}
            f1.append(_f1(pred[(0, 1)] | pred[(0, 2)], truth[(0, 1)] | truth[(0, 2)]))
            if w is not None:  # a holder is nobody of their own view
                for k in (1, 2):
                    assert not any(i == ids[k - 1] for _, i, _ in pred[(0, k)])
        assert f1[1] >= f1[0] - 0.02 and f1[1] > 0.8, (video, f1)
        placed = [s for s in said if s.startswith("--camera-id: each holder left out")]
        assert len(placed) == 1 and "hor1 mapped on 20 of 20 frames" in placed[0]
        assert ("sought near them" in placed[0] or "kept fewer" in placed[0]) == video
    with pytest.raises(ValueError, match="wearers: one per handheld view"):
        MultiGroundOptions((SIZE, SIZE), wearers=({},))
