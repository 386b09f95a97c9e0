"""datasets/tracking_video.py: the cameras a rendered video records are those it was drawn with,
and those it writes."""

from __future__ import annotations

import numpy as np
import pytest

from xvmatch.datasets.camera_frames import open_cameras
from xvmatch.datasets.synthetic_scenes import SCENARIOS, SynthConfig
from xvmatch.datasets.tracking_video import render_tracking_video, write_tracking_video
from xvmatch.geometry.matcher_inputs import wearer_row


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
