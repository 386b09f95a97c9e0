"""``xvmatch associate-multi``'s ``--mode``, ``--min-score``, ``--first-frame`` and ``--draw`` on
real box files (a small hand-made scene: a nadir top view and two horizontal views)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from xvmatch.cli import main
from xvmatch.inference.views.multi_ego_tracking import pairs_from_ids
from xvmatch.inference.views.multi_view_assignment import cycle_violations

N_FRAMES = 8


def _scene(folder: Path, ids=None, score: bool = False, first: int = 1) -> list[Path]:
    """Box files of four people walking, seen from above (20x20 boxes) and by two level
    cameras 640x360 (three people each); each view's ids its own (``ids``: per view, a
    function of (person, frame) giving the written id; default a per-view permutation)."""
    rng = np.random.default_rng(3)
    start, step = rng.uniform(-4, 4, (4, 2)), rng.uniform(-0.15, 0.15, (4, 2))
    own = [dict(zip(range(4), (rng.permutation(4) + 10 * (v + 1)).tolist(), strict=True))
           for v in range(3)]
    ids = ids or [lambda p, f, v=v: own[v][p] for v in range(3)]
    lines: list[list[str]] = [[], [], []]
    for f in range(N_FRAMES):
        pos = start + f * step
        for p in range(4):
            x, y = 320 + 30 * pos[p, 0], 180 + 30 * pos[p, 1]
            lines[0].append((f, ids[0](p, f), x - 10, y - 10, 20.0, 20.0))
        for v, people, cam in ((1, (0, 1, 2), (-8.0, 0.0)), (2, (1, 2, 3), (8.0, 0.0))):
            for p in people:
                dx, depth = pos[p, 1] - cam[1], abs(pos[p, 0] - cam[0]) + 2.0
                h = 300.0 / depth
                x = 320 + 300 * dx / depth
                lines[v].append((f, ids[v](p, f), x - h / 5, 200 - h / 2, h / 2.5, h))
    paths = []
    for name, rows in zip(("top", "hor1", "hor2"), lines, strict=True):
        text = "".join(f"{f + first},{i},{x:.2f},{y:.2f},{w:.2f},{h:.2f}"
                       + (f",{0.2 if (f + n) % 5 == 0 else 0.9}" if score else "") + "\n"
                       for n, (f, i, x, y, w, h) in enumerate(rows))
        path = folder / f"{name}.txt"
        path.write_text(text)
        paths.append(path)
    return paths


def _run(paths, out, *extra) -> int:
    top, *hor = paths
    return main(["associate-multi", "--top", str(top), "--hor", *map(str, hor), "--out",
                 str(out), "--image-size", "640x360", *extra])


def _rows(path: Path):
    return [(int(r[0]), int(r[1]), ",".join(r[2:]))
            for r in (line.split(",") for line in path.read_text().splitlines())]


def _check_people(paths, out):
    """Rows kept; on every frame one box per view and person, cycle-consistent."""
    pred = [_rows(out / p.name) for p in paths]
    for p, q in zip(paths, pred, strict=True):
        assert [(f, rest) for f, _, rest in _rows(p)] == [(f, rest) for f, _, rest in q]
    for f in sorted({f for f, _, _ in pred[0]}):
        ids = [np.array([i for g, i, _ in q if g == f]) for q in pred]
        assert all(np.unique(i).size == i.size for i in ids)
        assert not cycle_violations(pairs_from_ids(ids), [i.size for i in ids])
    return pred


def test_video_mode_keeps_every_frame_one_set_of_people(tmp_path, capsys):
    paths = _scene(tmp_path)
    assert _run(paths, tmp_path / "auto") == 0  # the ids persist: auto takes video mode
    assert "--mode video: each view's ids persist" in capsys.readouterr().err
    _check_people(paths, tmp_path / "auto")
    # video mode's person ids follow the top view's tracks over the frames
    top = _rows(tmp_path / "auto" / "top.txt")
    own = _rows(paths[0])
    held = {}
    for (_, track, _), (_, person, _) in zip(own, top, strict=True):
        held.setdefault(track, set()).add(person)
    assert all(len(s) == 1 for s in held.values())


def test_detector_ids_take_frame_mode_or_are_refused(tmp_path, capsys):
    paths = _scene(tmp_path, ids=[lambda p, f: -1] * 3)
    assert _run(paths, tmp_path / "auto") == 0
    err = capsys.readouterr().err
    assert "--mode video" not in err
    _check_people(paths, tmp_path / "auto")
    assert _run(paths, tmp_path / "video", "--mode", "video") == 2
    err = capsys.readouterr().err
    assert "--mode video:" in err and "holds an id twice" in err and "--mode frame" in err


def test_fresh_ids_every_frame_take_frame_mode(tmp_path, capsys):
    paths = _scene(tmp_path, ids=[lambda p, f: 100 * f + p] * 3)
    assert _run(paths, tmp_path / "auto") == 0
    assert "--mode video" not in capsys.readouterr().err
    assert _run(paths, tmp_path / "frame", "--mode", "frame", "--quiet") == 0
    _check_people(paths, tmp_path / "frame")
    assert all((tmp_path / "auto" / p.name).read_bytes() == (tmp_path / "frame" / p.name)
               .read_bytes() for p in paths)


def test_min_score_and_first_frame(tmp_path):
    paths = _scene(tmp_path, score=True, first=0)
    assert _run(paths, tmp_path / "out", "--min-score", "0.5", "--first-frame", "0",
                "--quiet") == 0
    for p in paths:
        kept = [r for r in _rows(p) if float(r[2].split(",")[4]) >= 0.5]
        got = _rows(tmp_path / "out" / p.name)
        assert [(f, rest) for f, _, rest in kept] == [(f, rest) for f, _, rest in got]
        assert len(got) < len(_rows(p))
    assert _run(paths, tmp_path / "zero", "--quiet") == 2  # frame 0 without --first-frame 0


def test_draw_writes_the_pairs_of_each_view_pair(tmp_path):
    paths = _scene(tmp_path)
    draw = tmp_path / "pictures"
    assert _run(paths, tmp_path / "out", "--draw", str(draw), "--draw-every", "3",
                "--quiet") == 0
    for k in (1, 2):
        assert len(sorted((draw / f"hor{k}").glob("frame_*"))) == len(range(0, N_FRAMES, 3))
    assert not (draw / "hor3").exists()
    # a second run may write into its own folder again; another command's folder is refused
    assert _run(paths, tmp_path / "out", "--draw", str(draw), "--quiet") == 0
    assert len(sorted((draw / "hor1").glob("frame_*"))) == N_FRAMES
    other = tmp_path / "other"
    other.mkdir()
    (other / "mine.txt").write_text("x")
    assert _run(paths, tmp_path / "out2", "--draw", str(other), "--quiet") == 2


@pytest.mark.parametrize("option", ["--mode", "--draw-every"])
def test_bad_options_are_refused(tmp_path, option, capsys):
    paths = _scene(tmp_path)
    bad = {"--mode": "tracks", "--draw-every": "0"}[option]
    with pytest.raises(SystemExit) as exc:
        _run(paths, tmp_path / "out", option, bad)
    assert exc.value.code == 2
    assert option in capsys.readouterr().err


def test_draw_names_each_picture_by_its_horizontal_frame(tmp_path):
    # top frame = horizontal frame + offset: hor1 (offset 2) meets the top view on its frames
    # 1-6, hor2 (offset -1) on its frames 2-8, as associate --draw names them
    paths = _scene(tmp_path)
    draw = tmp_path / "pictures"
    assert _run(paths, tmp_path / "out", "--offset", "2", "-1", "--draw", str(draw),
                "--quiet") == 0
    names = [sorted(p.name for p in (draw / f"hor{k}").glob("frame_*")) for k in (1, 2)]
    assert names == [[f"frame_{f:06d}.jpg" for f in range(1, 7)],
                     [f"frame_{f:06d}.jpg" for f in range(2, 9)]]
