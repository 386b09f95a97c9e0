"""The handheld camera's field of view chosen from its people (cues/hor_lens.py): on a small
synthetic clip seen through a known lens, the registration that explains the most people picks
a wide lens for an action camera and keeps the prior for a phone's."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.cues.ground_registration import hor_ground_points
from xvmatch.cues.hor_lens import (
    HFOV_CANDIDATES,
    MEASURED_RANGE,
    MIN_PEOPLE,
    NEAR_TIE,
    LensChoice,
    _pick,
    _subsample,
    choose_hor_hfov,
    implied_fit,
    implied_hfov,
    pick_along_tracks,
)

SIZE = (1280, 720)


def _clip(hfov_deg: float, seed: int = 0, n_frames: int = 6, heights: np.ndarray | None = None
          ) -> tuple[list[int], list[np.ndarray], list[np.ndarray]]:
    """People walking on a ground map, seen from above (their positions, a little noise) and by a
    handheld camera of ``hfov_deg`` walking among them (their boxes: height from distance, column
    from bearing, as :func:`~xvmatch.cues.ground_registration.hor_ground_points` reads them;
    the ten people 1.72 m tall, or ``heights``)."""
    heights = np.full(10, 1.72) if heights is None else heights
    rng = np.random.default_rng(seed)
    people = np.column_stack([rng.uniform(2.0, 20.0, 10), rng.uniform(-10.0, 10.0, 10)])
    walk = rng.normal(0.0, 0.4, (10, 2))
    f = 0.5 * SIZE[0] / np.tan(np.radians(hfov_deg) / 2.0)
    frames, tops, boxes = [], [], []
    for k in range(n_frames):
        t = 0.3 * k
        where = people + t * walk
        centre, heading = np.array([0.3 * t, 0.0]), 0.05 * t
        tops.append(where + rng.normal(0.0, 0.1, where.shape))
        c, s = np.cos(heading), np.sin(heading)
        rel = where - centre
        ahead, left = rel[:, 0] * c + rel[:, 1] * s, -rel[:, 0] * s + rel[:, 1] * c
        seen = (ahead > 1.0) & (np.abs(np.arctan2(left, ahead)) < np.radians(hfov_deg) / 2 - 0.02)
        height = f * heights[seen] / ahead[seen]
        column = 0.5 * SIZE[0] - f * left[seen] / ahead[seen]
        boxes.append(np.column_stack([column - 0.2 * height, np.full(seen.sum(), 100.0),
                                      0.4 * height, height]))
        frames.append(1 + 3 * k)
    return frames, tops, boxes


@pytest.fixture(scope="module")
def wide() -> LensChoice:
    frames, tops, boxes = _clip(110.0, n_frames=20)
    return choose_hor_hfov(frames, tops, boxes, SIZE, fps=10.0)


def test_an_action_camera_gets_a_wide_lens(wide: LensChoice) -> None:
    assert wide.hfov_deg >= 90.0
    assert set(wide.scores) == set(HFOV_CANDIDATES)
    assert wide.scores[wide.hfov_deg] > wide.scores[70.0]


def test_people_read_at_their_own_height_tell_the_lens() -> None:
    """People 1.5-1.95 m tall, each one's height over the crowd's known from the top view
    (``sizes``): read at 1.72 m the handheld map blurs and a 110-degree camera is taken for a
    narrower one; read at their own height the choice finds 110, above chance by more."""
    heights = np.random.default_rng(2).uniform(1.5, 1.95, 10)
    frames, tops, boxes = _clip(110.0, seed=0, n_frames=20, heights=heights)
    plain = choose_hor_hfov(frames, tops, boxes, SIZE, fps=10.0)
    sized = choose_hor_hfov(frames, tops, boxes, SIZE, fps=10.0,
                            sizes=[heights / 1.72] * len(frames))
    assert sized.hfov_deg == 110.0 and plain.hfov_deg != 110.0
    assert (sized.scores[110.0] - sized.chance[110.0]
            > plain.scores[110.0] - plain.chance[110.0])
    ones = choose_hor_hfov(frames, tops, boxes, SIZE, fps=10.0, sizes=[np.ones(10)] * 20)
    assert ones == plain  # everyone at the crowd's height: as without sizes
    with pytest.raises(ValueError, match="sizes must have one entry per frame"):
        choose_hor_hfov(frames, tops, boxes, SIZE, fps=10.0, sizes=[np.ones(10)])


def test_a_phone_keeps_the_prior() -> None:
    frames, tops, boxes = _clip(70.0, seed=1)
    choice = choose_hor_hfov(frames, tops, boxes, SIZE, fps=10.0)
    assert choice.hfov_deg == 70.0


def test_same_input_same_choice(wide: LensChoice) -> None:
    frames, tops, boxes = _clip(110.0, n_frames=20)
    again = choose_hor_hfov(frames, tops, boxes, SIZE, fps=10.0)
    assert again == wide


def test_a_small_lead_keeps_the_prior() -> None:
    frames, tops, boxes = _clip(90.0, seed=1, n_frames=20)
    choice = choose_hor_hfov(frames, tops, boxes, SIZE, fps=10.0, margin=100.0)
    assert max(choice.scores, key=choice.scores.get) != 70.0  # another lens leads
    assert choice.scores[70.0] > choice.chance[70.0] and choice.hfov_deg == 70.0


def test_lenses_are_compared_above_chance(wide: LensChoice) -> None:
    """A wide lens squeezes the handheld map, which then pairs more people by chance: each
    lens is also scored against its mirrored map's pairing."""
    assert set(wide.chance) == set(wide.scores)
    assert all(v > 0.0 for v in wide.chance.values())  # a crowd pairs somebody by chance
    above = {h: wide.scores[h] - wide.chance[h] for h in wide.scores}
    # Above chance, the 110-degree camera read as such pairs three times any other reading.
    assert all(above[110.0] > 3.0 * above[h] for h in above if h != 110.0)
    # With a person charged as missed at the round radius alone (a nadir top view's
    # registration), the 70-degree reading pairs nobody above chance.
    frames, tops, boxes = _clip(110.0, n_frames=20)
    plain = choose_hor_hfov(frames, tops, boxes, SIZE, fps=10.0, spread=0.0)
    assert plain.scores[70.0] - plain.chance[70.0] < 0.0 < plain.scores[110.0] - plain.chance[110.0]


def test_another_lens_only_with_a_clear_lead() -> None:
    no_chance = dict.fromkeys((50.0, 70.0, 90.0, 110.0), 0.0)
    scores = {70.0: 50.0, 90.0: 60.0, 110.0: 65.0}
    assert _pick(scores, no_chance, 70.0, 1.3) == 70.0  # 65 is not above 1.3 x 50
    scores[110.0] = 65.5
    assert _pick(scores, no_chance, 70.0, 1.3) == 110.0
    assert _pick({50.0: 80.0, 70.0: 50.0, 90.0: 80.0}, no_chance, 70.0, 1.3) == 50.0  # a tie
    # A lead that chance explains (the wide lens pairs more in all, not above chance) ...
    assert _pick({70.0: 50.0, 110.0: 70.0}, {70.0: 30.0, 110.0: 55.0}, 70.0, 1.3) == 70.0
    # ... and one it does not (30 above chance against 20, and 70 against 50 in all).
    assert _pick({70.0: 50.0, 110.0: 70.0}, {70.0: 30.0, 110.0: 40.0}, 70.0, 1.3) == 110.0
    # The prior pairs nothing above chance: the other lens must pair somebody above it.
    assert _pick({70.0: 20.0, 110.0: 30.0}, {70.0: 22.0, 110.0: 27.0}, 70.0, 1.3) == 110.0
    assert _pick({70.0: 20.0, 110.0: 30.0}, {70.0: 22.0, 110.0: 29.5}, 70.0, 1.3) == 70.0


def test_no_people_keeps_the_prior() -> None:
    empty = [np.zeros((0, 2))] * 3
    choice = choose_hor_hfov([1, 2, 3], empty, [np.zeros((0, 4))] * 3, SIZE, fps=10.0)
    assert choice.hfov_deg == 70.0


def test_frames_subsampled_evenly() -> None:
    assert _subsample(5, 20) == [0, 1, 2, 3, 4]
    picked = _subsample(40, 20)
    assert len(picked) == 20 and picked[0] == 0 and picked[-1] == 39
    frames, tops, boxes = _clip(70.0, n_frames=6)
    assert choose_hor_hfov(frames, tops, boxes, SIZE, fps=10.0, max_frames=3).frames == [
        frames[0], frames[2], frames[5]]


def test_bad_input() -> None:
    with pytest.raises(ValueError, match="one entry per frame"):
        choose_hor_hfov([1, 2], [np.zeros((0, 2))], [np.zeros((0, 4))] * 2, SIZE, fps=10.0)
    with pytest.raises(ValueError, match="max_frames must be at least 1"):
        choose_hor_hfov([1], [np.zeros((0, 2))], [np.zeros((0, 4))], SIZE, fps=10.0,
                        max_frames=0)


def test_video_mode_keeps_the_lens_whose_pairs_hold_along_the_tracks() -> None:
    assert pick_along_tracks({70.0: 40, 90.0: 78, 110.0: 78}) == 90.0  # a tie: nearer the prior
    assert pick_along_tracks({70.0: 76, 90.0: 77, 110.0: 77}) == 90.0  # no margin: counts
    assert pick_along_tracks({70.0: 152, 90.0: 0, 110.0: 152}) == 70.0
    assert pick_along_tracks({70.0: 0, 90.0: 71, 110.0: 179}) == 110.0
    assert pick_along_tracks({60.0: 5, 70.0: 0, 80.0: 5}, prior=70.0) == 60.0  # the narrower
    assert pick_along_tracks(dict.fromkeys(HFOV_CANDIDATES, 0)) == 70.0
    # One person held along the tracks says nothing of the lens: a pose puts anyone anywhere.
    one = {70.0: 0, 90.0: 39, 110.0: 0}
    assert pick_along_tracks(one) == 90.0
    assert pick_along_tracks(one, {70.0: 0, 90.0: 1, 110.0: 0}) == 70.0
    assert pick_along_tracks(one, {70.0: 0, 90.0: MIN_PEOPLE, 110.0: 0}) == 90.0
    assert pick_along_tracks({70.0: 30, 90.0: 39, 110.0: 60},
                             {70.0: 1, 90.0: 2, 110.0: 1}) == 90.0  # the prior needs none
    # A near tie (within NEAR_TIE) joining no more people keeps the prior; more people win.
    assert pick_along_tracks({70.0: 110, 90.0: 110, 110.0: 117},
                             {70.0: 3, 90.0: 3, 110.0: 3}) == 70.0
    assert pick_along_tracks({70.0: 181, 90.0: 182, 110.0: 146},
                             {70.0: 5, 90.0: 6, 110.0: 4}) == 90.0
    assert pick_along_tracks({70.0: 100, 90.0: 100 * NEAR_TIE + 1, 110.0: 0},
                             {70.0: 3, 90.0: 3, 110.0: 0}) == 90.0  # beyond the near tie
    with pytest.raises(ValueError, match="people must have the candidates of kept"):
        pick_along_tracks(one, {70.0: 0, 90.0: 1})
    with pytest.raises(ValueError, match=r"the prior lens 70\.0 must be among"):
        pick_along_tracks({90.0: 3, 110.0: 4})
    none = LensChoice(70.0, dict.fromkeys(HFOV_CANDIDATES, 0.0), {}, [1], along_tracks=True)
    kept = LensChoice(70.0, {70.0: 9.0, 90.0: 9.0, 110.0: 3.0}, {}, [1], along_tracks=True)
    wide = LensChoice(110.0, {70.0: 0.0, 90.0: 3.0, 110.0: 9.0}, {}, [1], along_tracks=True)
    assert not none.registered and none.why_prior == "no lens tried kept a pair along the tracks"
    assert kept.registered and kept.why_prior == "no other lens kept more pairs along the tracks"
    assert wide.registered and wide.why_prior is None


def _seen(true_hfov: float, used_hfov: float, rng: np.random.Generator, n: int, scale: float,
          turn: float) -> tuple[np.ndarray, np.ndarray]:
    """``n`` people in front of a level camera of ``true_hfov``: on a top map (turned by
    ``turn``, moved, ``scale`` times the metres) and on the handheld map read from their
    boxes with a lens of ``used_hfov`` (:func:`hor_ground_points`)."""
    ahead = rng.uniform(5.0, 30.0, n)
    half = np.radians(true_hfov) / 2 - 0.05
    left = ahead * np.tan(rng.uniform(-half, half, n))
    f = 0.5 * SIZE[0] / np.tan(np.radians(true_hfov) / 2)
    height = f * 1.72 / ahead
    column = 0.5 * SIZE[0] - f * left / ahead
    boxes = np.column_stack([column - 0.2 * height, np.full(n, 50.0), 0.4 * height, height])
    c, s = np.cos(turn), np.sin(turn)
    top = scale * np.column_stack([ahead, left]) @ np.array([[c, s], [-s, c]]) + [3.0, -7.0]
    return top, hor_ground_points(boxes, SIZE, used_hfov)


@settings(max_examples=60, deadline=None)
@given(true_hfov=st.floats(50.0, 120.0), used=st.sampled_from(HFOV_CANDIDATES),
       people=st.lists(st.integers(3, 9), min_size=1, max_size=4),
       scale=st.floats(0.7, 1.4), turn=st.floats(-np.pi, np.pi), seed=st.integers(0, 2**16))
def test_right_pairs_imply_the_true_lens_read_with_any_lens(
        true_hfov: float, used: float, people: list[int], scale: float, turn: float,
        seed: int) -> None:
    """A wrong lens stretches the handheld map along its axis only, so the right pairs give
    the true field of view back to the degree, whatever lens read them, at any map scale,
    heading and place, over one frame or several."""
    rng = np.random.default_rng(seed)
    frames = [_seen(true_hfov, used, rng, n, scale, turn + k) for k, n in enumerate(people)]
    implied = implied_hfov(used, [t for t, _ in frames], [h for _, h in frames])
    assert implied is not None and implied == round(implied)
    assert abs(implied - true_hfov) <= 0.5 + 1e-9


def test_right_pairs_fit_their_lens_better_than_swapped_ones() -> None:
    """The lens the right pairs imply comes with next to no stray (their distances fit it
    exactly); two people swapped stray more, and the lens is that of implied_hfov."""
    rng = np.random.default_rng(3)
    frames = [_seen(85.0, 70.0, rng, 6, 1.0, 0.4 + k) for k in range(3)]
    tops, hors = [t for t, _ in frames], [h for _, h in frames]
    lens, stray = implied_fit(70.0, tops, hors)
    assert (lens, stray) == (implied_hfov(70.0, tops, hors), 0.0)
    swapped = [h[[1, 0, *range(2, len(h))]] for h in hors]
    assert implied_fit(70.0, tops, swapped)[1] > 0.01
    assert implied_fit(70.0, [], []) is None


def test_a_lens_is_implied_only_where_the_pairs_tell() -> None:
    """Fewer than three distances, or people all straight ahead (no spread across: the depth
    stretch and the scale cannot be told apart), imply nothing; a fit beyond the pinhole
    lenses is held to :data:`MEASURED_RANGE`; frames must pair row for row."""
    rng = np.random.default_rng(0)
    top, hor = _seen(80.0, 70.0, rng, 3, 1.0, 0.3)
    assert implied_hfov(70.0, [top[:2], top[1:]], [hor[:2], hor[1:]]) is None  # 2 distances
    assert implied_hfov(70.0, [top], [hor]) == 80.0  # 3 distances
    assert implied_hfov(70.0, [], []) is None
    line = np.column_stack([[5.0, 9.0, 14.0, 20.0], np.zeros(4)])
    assert implied_hfov(70.0, [line * 1.3], [line]) is None
    wide, wide_hor = _seen(120.0, 70.0, rng, 6, 1.0, 0.0)
    assert implied_hfov(70.0, [wide], [wide_hor * [3.0, 1.0]]) == MEASURED_RANGE[1]
    assert implied_hfov(70.0, [wide], [wide_hor * [0.2, 1.0]]) == MEASURED_RANGE[0]
    with pytest.raises(ValueError, match="pair row for row"):
        implied_hfov(70.0, [top], [hor[:2]])
