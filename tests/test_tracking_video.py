"""datasets/tracking_video.py: the cameras a rendered video records are those it was drawn with,
and those it writes."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from xvmatch.cues.matcher_inputs import wearer_row
from xvmatch.datasets.synthetic_scenes import SCENARIOS, SynthConfig
from xvmatch.datasets.tracking_video import (
    FLIGHT_HEADING,
    render_tracking_video,
    write_tracking_video,
)
from xvmatch.formats.camera_frames import open_cameras


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_each_frame_records_the_cameras_that_find_the_wearer(scenario: str) -> None:
    # The egocentric camera is worn by person 0: its centre lies on that person's top-view box
    # (within a metre, or wearer_row says None), frame after frame as the head turns.
    video = render_tracking_video(3, 4, SynthConfig(scenario=scenario, n_people=(4, 6), fps=25.0))
    assert sorted(video.cameras) == sorted(video.top)
    for f, cams in video.cameras.items():
        row = wearer_row(cams, video.top[f].boxes)
        assert row is not None and int(video.top[f].ids[row]) == 0, f
    assert (video.cameras[1].hor.R != video.cameras[4].hor.R).any()


def test_written_cameras_read_back_as_rendered(tmp_path) -> None:
    # write_tracking_video's cameras/ folder is what --cameras reads: the same cameras, frame by
    # frame, to the last bit (the camera files keep full precision).
    video = render_tracking_video(3, 3, SynthConfig(scenario="overview", n_people=(4, 6),
                                                    fps=25.0))
    files = write_tracking_video(video, tmp_path)
    read = open_cameras(files["cameras"], sorted(video.top))
    for f, cams in video.cameras.items():
        for mine, theirs in ((read.get(f).top, cams.top), (read.get(f).hor, cams.hor)):
            for name in ("K", "R", "c"):
                np.testing.assert_array_equal(getattr(mine, name), getattr(theirs, name))
            assert mine.image_size == theirs.image_size


def test_a_flying_top_camera_moves_and_turns_over_the_same_walk() -> None:
    # flight=(2 m/s, 5 deg/s): frame 3 is 2/25 s after frame 1, so the top camera is 0.16 m
    # further along FLIGHT_HEADING and turned 0.4 degrees about the vertical; the people, the
    # egocentric camera and its boxes are those of the fixed render of the same seed.
    config = SynthConfig(scenario="drone", n_people=(4, 6), fps=25.0)
    fixed = render_tracking_video(3, 3, config)
    flying = render_tracking_video(3, 3, config, flight=(2.0, 5.0))
    first, last = flying.cameras[1].top, flying.cameras[3].top
    np.testing.assert_allclose(last.c - first.c, 0.16 * FLIGHT_HEADING, atol=1e-12)
    turn = Rotation.from_matrix(last.R.T @ first.R)  # the world turn between the two
    np.testing.assert_allclose(turn.as_rotvec(degrees=True), [0.0, 0.0, 0.4], atol=1e-9)
    np.testing.assert_allclose(first.c + last.c, 2 * fixed.cameras[2].top.c, atol=1e-12)
    for f in fixed.hor:
        np.testing.assert_array_equal(flying.hor[f].boxes, fixed.hor[f].boxes)
        np.testing.assert_array_equal(flying.cameras[f].hor.R, fixed.cameras[f].hor.R)
    assert any(not np.array_equal(flying.top[f].boxes, fixed.top[f].boxes) for f in fixed.top)
