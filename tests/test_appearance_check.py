"""The appearance check (inference/matching/appearance_check.py): a run's appearance cue judged on
its own box-only pseudo-matches; synthetic cost matrices for the rule, a rendered video through the
shipped bundle for ``associate_sequence_learned`` and the command line."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from xvmatch.cli import main
from xvmatch.datasets.synthetic_scenes import SynthConfig
from xvmatch.datasets.tracking_video import render_tracking_video, write_tracking_video
from xvmatch.formats.mot_boxes import FrameBoxes, read_mot_boxes
from xvmatch.inference.adaptation.adaptation_pairs import MiningConfig
from xvmatch.inference.adaptation.site_adaptation import SiteAdaptation
from xvmatch.inference.linking.assignment import FrameCosts
from xvmatch.inference.linking.tracklets import Tracklet
from xvmatch.inference.matching.appearance_check import (
    CONSISTENCY_WINDOW,
    MIN_AUC,
    MIN_CONSISTENCY,
    MIN_PAIRS,
    SITE_MIN_AUC,
    TRACK_MIN_AUC,
    TRACK_MIN_PAIRS,
    AppearanceCheck,
    check_appearance,
    check_tracklet_appearance,
    sure_pair_consistency,
)
from xvmatch.inference.matching.learned_association import (
    LearnedMatcher,
    associate_sequence_learned,
    load_matcher_bundle,
)

PEOPLE = 5


def _still(frames: int) -> tuple[dict, dict]:
    """``frames`` consecutive frames of PEOPLE standing people in each view (fixed boxes: one
    tracklet each), ids only naming boxes (the horizontal ones in another order)."""
    boxes = np.array([[40.0 * k, 10.0, 20.0, 50.0] for k in range(PEOPLE)])
    top = {f: FrameBoxes(f, np.arange(1, PEOPLE + 1), boxes) for f in range(1, frames + 1)}
    hor = {f: FrameBoxes(f, np.arange(PEOPLE, 0, -1) + 100, boxes) for f in range(1, frames + 1)}
    return top, hor


def _costs(frames: int, app: str, seed: int = 0) -> tuple[dict, dict]:
    """Box-only costs sure of the diagonal, and an appearance cue that agrees with it, says the
    opposite or is noise."""
    rng = np.random.default_rng(seed)
    box = np.full((PEOPLE, PEOPLE), 0.9)
    np.fill_diagonal(box, 0.05)
    out = {}
    for f in range(1, frames + 1):
        noise = rng.uniform(0, 0.05, (PEOPLE, PEOPLE))
        cue = {"agrees": np.where(np.eye(PEOPLE, dtype=bool), 0.1, 0.5),
               "opposite": np.where(np.eye(PEOPLE, dtype=bool), 0.5, 0.1),
               "noise": rng.uniform(0.2, 0.6, (PEOPLE, PEOPLE))}[app]
        out[f] = cue + noise
    return {f: box.copy() for f in range(1, frames + 1)}, out


@pytest.mark.parametrize(("app", "trusted"), [("agrees", True), ("opposite", False),
                                               ("noise", False)])
def test_a_cue_is_judged_on_the_box_only_pseudo_matches(app: str, trusted: bool) -> None:
    top, hor = _still(100)
    box, cue = _costs(100, app)
    check = check_appearance(top, hor, box, cue, gamma=0.5)
    assert check.judged and check.trusted is trusted
    assert check.positives >= MIN_PAIRS and check.negatives >= MIN_PAIRS
    assert check.auc == (1.0 if app == "agrees" else check.auc)
    assert (check.auc + 2 * check.error >= check.min_auc) is trusted
    assert ("images used" in check.message()) is trusted
    assert ("matched from the boxes alone" in check.message()) is not trusted


def test_too_few_pairs_keep_the_images() -> None:
    """Fewer consecutive frames than a burst, or a box-only matcher that is never sure: not
    judged, and the images are used as before."""
    top, hor = _still(6)
    box, cue = _costs(6, "opposite")
    short = check_appearance(top, hor, box, cue, gamma=0.5)
    assert not short.judged and short.trusted and math.isnan(short.auc)
    assert "needed to judge the images" in short.message()
    assert short.bursts == 0 and not short.worth_saying  # single images: nothing to say
    assert not short.to_tell(quiet=False)
    top, hor = _still(40)
    box, cue = _costs(40, "opposite")
    unsure = {f: np.full_like(c, 0.45) for f, c in box.items()}  # never below gamma by 0.3
    check = check_appearance(top, hor, unsure, cue, gamma=0.5)
    assert not check.judged and check.trusted and check.positives == 0
    assert check.bursts == 4 and check.worth_saying  # a video the matcher is never sure of
    assert check.to_tell(quiet=False) and not check.to_tell(quiet=True)  # images kept
    top, hor = _still(100)
    box, cue = _costs(100, "opposite")
    strict = check_appearance(top, hor, box, cue, gamma=0.5, min_pairs=10_000)
    assert not strict.judged and strict.min_pairs == 10_000
    assert "10000 needed to judge" in strict.message()  # the bar it was held to, not the default


def test_a_few_pairs_do_not_condemn_a_cue() -> None:
    """A cue of AUC 0.55 exactly (each pseudo-match costs 0.3, 11 of its frame's 20 other pairs
    0.4 and 9 of them 0.2) passes on 2 bursts (its interval reaches 0.62) and fails on 20."""
    weak = np.where(np.eye(PEOPLE, dtype=bool), 0.3, 0.2)
    off = np.nonzero(~np.eye(PEOPLE, dtype=bool))
    weak[off[0][:11], off[1][:11]] = 0.4
    for frames, trusted in ((20, True), (200, False)):
        top, hor = _still(frames)
        box, _ = _costs(frames, "agrees")
        check = check_appearance(top, hor, box, {f: weak for f in box}, gamma=0.5)
        assert check.judged and check.auc == pytest.approx(0.55)
        assert check.trusted is trusted, check


def _wandering(box: dict, every: int) -> dict:
    """``box`` with the sure partner of every top row moved on by one every ``every`` frames
    (a box-only matcher sure of a different, wrong partner as the people move)."""
    return {f: np.roll(c, (f - 1) // every, axis=1) for f, c in box.items()}


def test_consistency_is_the_share_of_sure_frames_with_the_usual_partner() -> None:
    """A steady matcher scores 1; one that moves each person on every 20 frames keeps the most
    frequent partner for 40 of the window's 150 sure frames; a run shorter than the window is
    not measured."""
    top, hor = _still(200)
    box, _ = _costs(200, "agrees")
    assert sure_pair_consistency(top, hor, box, gamma=0.5) == 1.0
    assert sure_pair_consistency(top, hor, _wandering(box, 20), gamma=0.5) == pytest.approx(
        40 / CONSISTENCY_WINDOW)
    short = {f: c for f, c in box.items() if f <= CONSISTENCY_WINDOW - 1}
    assert math.isnan(sure_pair_consistency(top, hor, short, gamma=0.5))


def test_a_matcher_sure_of_changing_partners_does_not_judge_the_cue() -> None:
    """Each burst's pseudo-matches agree within the burst, but the box-only matcher changes
    everyone's partner over time: the cue (right) would be condemned on them; instead it is not
    judged and the images are used, and the user is told why."""
    top, hor = _still(200)
    box, cue = _costs(200, "agrees")
    steady = check_appearance(top, hor, box, cue, gamma=0.5)
    assert steady.judged and steady.consistency == 1.0
    check = check_appearance(top, hor, _wandering(box, 20), cue, gamma=0.5)
    assert check.positives >= MIN_PAIRS  # enough pairs: judged before the consistency gate
    assert not check.judged and check.trusted and math.isnan(check.auc)
    assert check.consistency < MIN_CONSISTENCY and check.worth_saying
    assert "change partners over time" in check.message()
    assert "0.27 of those frames" in check.message()
    assert not check.to_tell(quiet=True)  # images kept: said only without --quiet
    # shorter than the window, the consistency is not measured and the pairs condemn the cue
    short = {f: c for f, c in _wandering(box, 20).items() if f < CONSISTENCY_WINDOW}
    old = check_appearance(top, hor, short, cue, gamma=0.5)
    assert old.judged and not old.trusted and math.isnan(old.consistency)


def _clips(n_clips: int, length: int, box: np.ndarray, cue: np.ndarray):
    """``n_clips`` clips of ``length`` frames with PEOPLE standing people per view (one
    tracklet each, ids = rows unique over the view, the horizontal ones in another order),
    every frame's box-only costs ``box`` and the clip's tracklet cue ``cue``."""
    clips, costs = [], {}
    for k in range(n_clips):
        frames = np.arange(k * length + 1, (k + 1) * length + 1)
        top_rows = [np.arange(PEOPLE) + 1000 * f for f in frames]
        hor_rows = [np.arange(PEOPLE)[::-1] + 1000 * f + 500 for f in frames]
        top = [Tracklet(k, frames, np.array([r[p] for r in top_rows]), np.zeros((length, 4)))
               for p in range(PEOPLE)]
        hor = [Tracklet(k, frames, np.array([r[PEOPLE - 1 - p] for r in hor_rows]),
                        np.zeros((length, 4))) for p in range(PEOPLE)]
        for f, t, h in zip(frames.tolist(), top_rows, hor_rows, strict=True):
            costs[f] = FrameCosts(t, h, box[:, ::-1], np.zeros((PEOPLE, PEOPLE), bool))
        clips.append((top, hor, cue))
    return clips, costs


@pytest.mark.parametrize(("app", "trusted"), [("agrees", True), ("opposite", False),
                                               ("noise", False)])
def test_track_judges_its_cross_view_cue_on_sure_tracklet_pairs(app: str, trusted: bool) -> None:
    """``track``'s check: tracklets whose boxes the box-only matcher pairs surely on 3
    consecutive frames are pseudo-matches (the horizontal rows come in another order: the
    check follows the rows, not the positions); the cue between the clip's tracklets is judged
    on them as ``associate`` judges its boxes."""
    box, cue = _costs(1, app, seed=3)
    clips, costs = _clips(8, 10, box[1], cue[1])
    check = check_tracklet_appearance(clips, costs, gamma=0.5)
    assert check.judged and check.trusted is trusted and check.tracklets
    assert (check.positives, check.negatives, check.bursts) == (8 * PEOPLE, 8 * PEOPLE * 8, 8)
    assert ("tracklet pairs" in check.message()) and ("clips" in check.message())
    assert ("the cross-view weights come from the boxes alone" in check.message()) is not trusted
    few = check_tracklet_appearance(clips[:3], costs, gamma=0.5)  # 15 positives
    assert not few.judged and few.trusted and few.worth_saying
    assert few.min_pairs == TRACK_MIN_PAIRS and few.min_auc == TRACK_MIN_AUC
    assert f"{TRACK_MIN_PAIRS} needed to judge" in few.message()
    short, short_costs = _clips(8, 2, box[1], cue[1])  # never 3 consecutive sure frames
    unsure = check_tracklet_appearance(short, short_costs, gamma=0.5)
    assert unsure.positives == 0 and not unsure.judged
    assert check_tracklet_appearance(short, short_costs, 0.5, MiningConfig(agree=2)).judged
    with pytest.raises(ValueError, match="appearance cost is"):
        check_tracklet_appearance([(clips[0][0], clips[0][1][:2], cue[1])], costs, 0.5)


@pytest.fixture(scope="module")
def video(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("checked_video")
    v = render_tracking_video(2, 40, SynthConfig(scenario="drone", n_people=(8, 12), fps=25.0))
    return write_tracking_video(v, folder)


class _Folder:
    """PNG frames of a folder, optionally replaced by grey (a camera that keeps nothing of the
    people: every crop the same)."""

    def __init__(self, folder: Path, grey: bool = False) -> None:
        self.folder, self.grey = folder, grey

    def get(self, frame: int) -> np.ndarray:
        import cv2

        image = cv2.imread(str(self.folder / f"{frame:06d}.png"))
        return np.full_like(image, 128) if self.grey else image


@pytest.mark.slow
def test_associate_drops_images_only_where_the_check_fails(video) -> None:
    """On the shipped bundle: clean renders pass and give the images' matches; grey images
    fail and give exactly the boxes-only matches; off, the images are always used."""
    model = load_matcher_bundle("default")
    top, hor = read_mot_boxes(video["top"]), read_mot_boxes(video["hor"])
    import cv2

    h, w = cv2.imread(str(video["hor_images"] / "000001.png")).shape[:2]

    def run(grey: bool | None, check: bool):
        checked: list[AppearanceCheck] = []
        images = {} if grey is None else {
            "top_images": _Folder(video["top_images"], grey),
            "hor_images": _Folder(video["hor_images"], grey)}
        pairs = associate_sequence_learned(top, hor, w, model, hor_height=h,
                                           appearance_check=check, checked=checked, **images)
        return pairs, checked

    boxes, none = run(None, True)
    assert none == []  # nothing to judge without images
    clean, (passed,) = run(False, True)
    assert passed.judged and passed.trusted and passed.auc > 0.8
    assert clean == run(False, False)[0]
    greyed, (failed,) = run(True, True)
    assert failed.judged and not failed.trusted and failed.auc == 0.5
    assert greyed == boxes
    unchecked, nothing = run(True, False)
    assert nothing == [] and unchecked != boxes


@pytest.mark.slow
def test_a_site_bundle_is_held_to_the_higher_bar(video) -> None:
    """The same cue (an identity adaptation) and the same AUC, judged against SITE_MIN_AUC
    once it comes from a site bundle."""
    import cv2

    default = load_matcher_bundle("default")
    site = LearnedMatcher(dataclasses.replace(default.bundle, adaptation=SiteAdaptation.identity(
        default.bundle.manifest.appearance.dim("descriptors"))))
    top, hor = read_mot_boxes(video["top"]), read_mot_boxes(video["hor"])
    h, w = cv2.imread(str(video["hor_images"] / "000001.png")).shape[:2]
    checks = []
    for model in (default, site):
        checked: list[AppearanceCheck] = []
        associate_sequence_learned(top, hor, w, model, hor_height=h, appearance_check=True,
                                   checked=checked, top_images=_Folder(video["top_images"]),
                                   hor_images=_Folder(video["hor_images"]))
        checks.append(checked[0])
    assert [c.min_auc for c in checks] == [MIN_AUC, SITE_MIN_AUC] and MIN_AUC < SITE_MIN_AUC
    assert checks[0].auc == checks[1].auc and checks[1].judged
    assert checks[1].trusted is (checks[1].auc + 2 * checks[1].error >= SITE_MIN_AUC)


@pytest.mark.slow
def test_associate_command_says_what_the_check_found(video, tmp_path, capsys) -> None:
    args = ["associate", "--model", "default", "--top", str(video["top"]), "--hor",
            str(video["hor"]), "--top-images", str(video["top_images"]), "--hor-images",
            str(video["hor_images"]), "--quiet"]
    assert main([*args, "--out", str(tmp_path / "a.csv")]) == 0
    assert "appearance check" not in capsys.readouterr().err  # quiet, and the images passed
    costs = tmp_path / "costs.json"
    assert main([*args[:-1], "--out", str(tmp_path / "b.csv"), "--costs", str(costs)]) == 0
    assert "appearance check: the images tell the" in capsys.readouterr().err
    record = json.loads(costs.read_text())["appearance_check"]
    assert record["judged"] and record["images_used"] and record["auc"] > 0.8
    assert record["positives"] >= MIN_PAIRS and record["min_auc"] == MIN_AUC
    assert record["min_pairs"] == MIN_PAIRS
    assert main([*args[:-1], "--appearance-check", "off", "--out", str(tmp_path / "c.csv"),
                 "--costs", str(costs)]) == 0
    assert "appearance check" not in capsys.readouterr().err
    assert "appearance_check" not in json.loads(costs.read_text())
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "c.csv").read_bytes()


def _grey_copy(video: dict[str, Path], folder: Path) -> dict[str, Path]:
    """The video's image folders with every frame grey, under ``folder``."""
    import cv2

    grey = {}
    for view in ("top_images", "hor_images"):
        grey[view] = folder / view
        grey[view].mkdir()
        for png in sorted(video[view].glob("*.png")):
            image = cv2.imread(str(png))
            cv2.imwrite(str(grey[view] / png.name), np.full_like(image, 128))
    return grey


@pytest.mark.slow
def test_track_command_leaves_out_a_failed_cross_view_cue(video, tmp_path, capsys) -> None:
    """``track --model``: clean renders pass (the same tracks as unchecked); grey images fail
    and the line says the cross-view weights come from the boxes alone (also with --quiet)."""
    base = ["track", "--model", "default", "--top", str(video["top"]), "--hor",
            str(video["hor"]), "--clip-length", "5"]
    clean = ["--top-images", str(video["top_images"]), "--hor-images", str(video["hor_images"])]
    assert main([*base, *clean, "--out", str(tmp_path / "a")]) == 0
    err = capsys.readouterr().err
    assert "tracklet pairs the boxes alone are sure of from" in err and "images used" in err
    assert main([*base, *clean, "--appearance-check", "off", "--quiet",
                 "--out", str(tmp_path / "b")]) == 0
    assert "appearance check" not in capsys.readouterr().err
    for name in ("top.txt", "hor.txt"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    grey = _grey_copy(video, tmp_path)
    greyed = ["--top-images", str(grey["top_images"]), "--hor-images", str(grey["hor_images"])]
    assert main([*base, *greyed, "--quiet", "--out", str(tmp_path / "c")]) == 0
    err = capsys.readouterr().err
    assert "AUC 0.500" in err and "the cross-view weights come from the boxes alone" in err
    assert main([*base, *greyed, "--quiet", "--appearance-check", "off",
                 "--out", str(tmp_path / "d")]) == 0
    assert "appearance check" not in capsys.readouterr().err


@pytest.mark.slow
def test_associate_multi_judges_each_egocentric_view(video, tmp_path, capsys) -> None:
    """associate-multi judges each top-ego pass: grey images of the one horizontal view fail
    and its people come out exactly as from the boxes alone."""
    import cv2

    grey = _grey_copy(video, tmp_path)
    # --mode frame: each frame's pairs are what the images change (video mode would keep
    # them consistent along the tracks, which the boxes alone already get right here).
    base = ["associate-multi", "--model", "default", "--top", str(video["top"]), "--hor",
            str(video["hor"]), "--quiet", "--mode", "frame"]
    size = "x".join(map(str, cv2.imread(str(grey["hor_images"] / "000001.png")).shape[1::-1]))
    assert main([*base, "--image-size", size, "--out", str(tmp_path / "boxes")]) == 0
    assert main([*base, "--top-images", str(grey["top_images"]), "--hor-images",
                 str(grey["hor_images"]), "--out", str(tmp_path / "grey")]) == 0
    err = capsys.readouterr().err
    assert f"--hor {video['hor']}: appearance check:" in err and "from the boxes alone" in err
    for name in ("top.txt", "hor1.txt"):
        assert (tmp_path / "grey" / name).read_bytes() == (tmp_path / "boxes" / name).read_bytes()
    assert main([*base, "--top-images", str(grey["top_images"]), "--hor-images",
                 str(grey["hor_images"]), "--appearance-check", "off",
                 "--out", str(tmp_path / "unchecked")]) == 0
    assert "appearance check" not in capsys.readouterr().err
    assert (tmp_path / "unchecked" / "hor1.txt").read_bytes() != \
        (tmp_path / "boxes" / "hor1.txt").read_bytes()  # grey images do change the matches


def test_single_image_pairs_say_nothing_of_the_check(video, tmp_path, capsys) -> None:
    """Two frames hold no run of consecutive frames to judge: no line about the check."""
    from xvmatch.formats.mot_boxes import write_mot_boxes

    for view in ("top", "hor"):
        write_mot_boxes(tmp_path / f"{view}.txt",
                        {f: r for f, r in read_mot_boxes(video[view]).items() if f <= 2})
    assert main(["associate", "--model", "default", "--top", str(tmp_path / "top.txt"), "--hor",
                 str(tmp_path / "hor.txt"), "--top-images", str(video["top_images"]),
                 "--hor-images", str(video["hor_images"]), "--out", str(tmp_path / "p.csv")]) == 0
    err = capsys.readouterr().err
    assert "wrote" in err and "appearance check" not in err
