"""Whether the nadir search's assumptions hold: its handheld camera kept at one top-view person
over the clip, and a top view whose people are seen from above.

The spatial-distribution search (CVMHAT, Sec. 3.2) puts the handheld camera at a top-view
person O in every frame: the camera's wearer, whom a CVMHAT drone sees. Followed by the top
view's track ids (video mode), O stays with that person where they are in the top view; where
the holder is not (a phone on a sideline, a nadir drone over someone else's camera), each frame
takes whoever fits best and O wanders from person to person, and so do the pairs. On the 10
CVMHAT development pairs the most frequent O holds 0.80-0.99 of a clip's frames (all frames;
one pair, whose search pairs 63.5 CVIDF1 and the ground maps 88.4, 0.44); on 24 rendered
drones 80-90 degrees down (holders in the top view or not) the 8 clips the search paired at
0.75 pair F1 or better held 0.75 or more, and 13 of the 15 it paired under 0.6 held under 0.7
(docs/notes/oblique_top_camera.md, sixty-sixth session). A clip under :data:`MIN_CAMERA_HELD`
is said: ``--top-view oblique`` pairs on the ground maps wherever the camera stands.

The commands that take the search whatever the top camera (``track``'s cross-view evidence,
``offset``'s estimate) say where the top view's people stand upright (:func:`upright_top_warning`):
an oblique camera, which the search reads as a drone looking straight down.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping

__all__ = ["MIN_CAMERA_HELD", "camera_held", "followed_cameras", "upright_top_warning",
           "wandering_camera_note"]

MIN_CAMERA_HELD = 0.7
"""The least share of the searched frames whose O is the clip's most frequent one for the search
to read as having followed one camera holder (between the renders' failures, mostly under 0.55,
and CVMHAT's and the renders' good clips, 0.75 and over; CVMHAT's lowest but one, 0.80)."""


def followed_cameras(top: Mapping, rows: Mapping[int, int], video: bool
                     ) -> dict[int, int] | None:
    """Each frame's camera location O (``rows``: ``{frame: O's row in the top record}``, as
    :func:`~xvmatch.cues.spatial_search.associate_sequence` reports it) as the person it is
    followed by over time: the top view's track id in ``video`` mode; else the track of its
    boxes linked by IoU (:func:`~xvmatch.inference.linking.tracklets.box_track_ids`, the ids
    unread: a detector's). None in frame mode where the top view's boxes jump like independent
    pictures' (nobody to follow)."""
    if video:
        return {f: int(top[f].ids[r]) for f, r in rows.items()}
    from xvmatch.cues.box_motion import jumps_like_frames
    from xvmatch.inference.linking.tracklets import box_track_ids

    if jumps_like_frames(top):
        return None
    linked, start, n = box_track_ids(top), {}, 0
    for f in sorted(f for f in top if len(top[f].ids)):  # stack_frames' order
        start[f], n = n, n + len(top[f].ids)
    return {f: int(linked[start[f] + r]) for f, r in rows.items()}


def camera_held(cameras: Mapping[int, int]) -> float | None:
    """The share of frames whose camera location O (``{frame: person}``,
    :func:`followed_cameras`) is the clip's most frequent O; None where no frame found one."""
    if not cameras:
        return None
    return Counter(cameras.values()).most_common(1)[0][1] / len(cameras)


def wandering_camera_note(cameras: Mapping[int, int]) -> str | None:
    """The line saying that the search's camera did not stay with one top-view person (its
    holder not in the top view, or not found there), and what to give instead; None where it
    held (:data:`MIN_CAMERA_HELD`)."""
    held = camera_held(cameras)
    if held is None or held >= MIN_CAMERA_HELD:
        return None
    return (f"the search put the handheld camera at one top-view person in only "
            f"{100 * held:.0f} % of the frames: it did not find the holder among the top view's "
            "people, as it assumes, and its pairs may be wrong; --top-view oblique "
            "--top-image-size WxH pairs through the ground maps wherever the camera stands "
            "(slower), --camera-id ID names the holder")


def upright_top_warning(top: Mapping, search: str, what: str, instead: str,
                        level: str = "warning") -> str | None:
    """The line (a ``level``: ``warning`` or ``note``) saying that the top view's people
    (``{frame: FrameBoxes}``) stand upright (median box height over width at least
    :data:`~xvmatch.geometry.people_calibration.STEEP_ASPECT`: an oblique camera), which the
    ``search`` reads as a drone looking straight down, so ``what`` it gives may be wrong, and
    what to give ``instead``; None where they do not (a nadir view, no boxes). On issue 67's
    real low drones the search paired 9.7 CVIDF1."""
    from xvmatch.formats.box_image_size import upright_aspect

    if (aspect := upright_aspect(top)) is None:
        return None
    return (f"xvmatch: {level}: the top view's people stand upright (boxes {aspect:.1f} times as "
            f"tall as wide): an oblique camera, which {search} reads as a drone looking straight "
            f"down, so {what} may be wrong; {instead}")
