"""``xvmatch evaluate --tracks`` where TrackEval is not installed (issue 29, item 4).

The command runs in a fresh process whose imports of ``trackeval`` fail (a meta-path finder
put first refuses it, as for a package that is not installed): it prints the cross-view scores
it can compute, then one line naming the package the per-view metrics need, and exits 0.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest

from xvmatch.cli import main
from xvmatch.commands.evaluate_tracks import TRACKEVAL_MISSING
from xvmatch.datasets.box_scene import simulate_box_scene
from xvmatch.formats.mot_boxes import write_mot_boxes

WITHOUT_TRACKEVAL = textwrap.dedent("""
    import sys

    class NoTrackEval:
        def find_spec(self, name, path=None, target=None):
            if name == "trackeval" or name.startswith("trackeval."):
                raise ModuleNotFoundError(f"No module named {name!r}", name=name)
            return None

    sys.meta_path.insert(0, NoTrackEval())
    from xvmatch.cli import main
    raise SystemExit(main(sys.argv[1:]))
""")


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Ground truth of a simulated scene, and tracks: the ground truth with one hor id moved
    to another person, so that the cross-view scores are not all 100."""
    folder = tmp_path_factory.mktemp("tracks")
    scene = simulate_box_scene(n_frames=10, seed=2)
    write_mot_boxes(folder / "gt_top.txt", scene.top)
    write_mot_boxes(folder / "gt_hor.txt", scene.hor)
    (folder / "tracks").mkdir()
    (folder / "tracks" / "top.txt").write_text((folder / "gt_top.txt").read_text())
    lines = (folder / "gt_hor.txt").read_text().splitlines()
    first = lines[0].split(",")
    lines[0] = ",".join([first[0], "987654", *first[2:]])
    (folder / "tracks" / "hor.txt").write_text("\n".join(lines) + "\n")
    return folder


def _argv(folder, *extra):
    return ["evaluate", "--tracks", str(folder / "tracks"), "--top", str(folder / "gt_top.txt"),
            "--hor", str(folder / "gt_hor.txt"), *extra]


def _without_trackeval(argv):
    return subprocess.run([sys.executable, "-c", WITHOUT_TRACKEVAL, *argv], capture_output=True,
                          text=True, timeout=120)


@pytest.mark.slow
def test_the_cross_view_scores_and_one_line_naming_the_package(files):
    run = _without_trackeval(_argv(files))
    assert run.returncode == 0, run.stderr
    assert run.stderr.splitlines() == [TRACKEVAL_MISSING]
    assert "pip install --no-deps trackeval" in TRACKEVAL_MISSING
    head, row = run.stdout.splitlines()[0].split(), run.stdout.splitlines()[-1].split()
    assert head[:5] == ["name", "frames", "CVIDP", "CVIDR", "CVIDF1"]
    assert 0 < float(row[head.index("CVIDF1")]) < 100


@pytest.mark.slow
def test_json_gives_the_same_cross_view_scores_as_with_trackeval(files, capsys):
    run = _without_trackeval(_argv(files, "--json"))
    assert run.returncode == 0, run.stderr
    alone = json.loads(run.stdout)
    assert alone["top"] is None and alone["hor"] is None
    pytest.importorskip("trackeval")
    capsys.readouterr()
    assert main(_argv(files, "--json")) == 0
    full = json.loads(capsys.readouterr().out)
    assert alone["cross_view"] == full["cross_view"]
    assert full["top"]["idf1"] > 0


def test_the_blocker_really_hides_the_package():
    code = WITHOUT_TRACKEVAL.split("from xvmatch.cli")[0] + "import trackeval\n"
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60)
    assert run.returncode == 1 and "ModuleNotFoundError" in run.stderr
