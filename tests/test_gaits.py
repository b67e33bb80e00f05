"""`smol-dsl render`: elites of a real run drawn by MuJoCo's renderer (headless, EGL or
OSMesa), as GIF, MP4 and a self-contained page; bad input is exit 2 with one message."""

from __future__ import annotations

import base64
import io
import itertools
import re

import numpy as np
import pytest
from PIL import Image
from small_runs import cli

from smol_dsl.results import gaits
from smol_dsl.rundir import load_archive

STEPS = 30
REPORTED = re.compile(r"cell (\d+), (.+?) body \((.+?)\): fitness (\S+) \(archive (\S+)\), descriptor \((.+?)\)")


@pytest.fixture(scope="module")
def best_gif(small_run, tmp_path_factory, capsys_module):
    out = tmp_path_factory.mktemp("gaits") / "best.gif"
    code, out_text, err = capsys_module(["render", str(small_run), "-o", str(out), "--steps", str(STEPS)])
    assert code == 0, err
    return out, out_text


@pytest.fixture(scope="module")
def capsys_module():
    """main(argv) with stdout and stderr captured, for module-scoped fixtures."""
    import contextlib

    from smol_dsl.cli import main

    def run(argv):
        stdout, stderr = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
            code = main(argv)
        assert "Traceback" not in stderr.getvalue()
        return code, stdout.getvalue(), stderr.getvalue()

    return run


def gif_frames(path):
    image = Image.open(path)
    frames, delays = [], []
    for index in range(image.n_frames):
        image.seek(index)
        frames.append(np.asarray(image.convert("RGB"), dtype=np.int16))
        delays.append(image.info["duration"])
    return frames, delays


def test_the_best_elite_renders_in_real_time_and_scores_as_the_archive_says(best_gif, small_run):
    out, printed = best_gif
    archive = load_archive(small_run)
    cell, label, _, fitness, archive_fitness, _ = REPORTED.search(printed).groups()
    assert int(cell) == archive.best_cell and label == "final"
    assert fitness == archive_fitness == f"{float(archive.fitnesses[archive.best_cell]):.4f}"  # the scoring's own
    frames, delays = gif_frames(out)
    stride = gaits.frame_stride(0.008)  # walker2d's environment step
    assert stride * 8 >= gaits.MIN_FRAME_MS and set(delays) == {stride * 8}
    assert 2 <= len(frames) <= STEPS // stride + 1  # every frame of the episode (fewer if it fell)
    assert f"{len(frames)} frames of {stride * 8} ms" in printed
    moved = [np.abs(a - b).mean() for a, b in itertools.pairwise(frames)]
    assert min(moved) > 0.05, moved  # every frame differs from the one before: the robot moves
    last = frames[-1][16:]  # below the label
    assert last.std() > 10  # not a blank image: floor, sky and robot


def test_the_child_and_the_adult_side_by_side_in_one_page(small_run, tmp_path, capsys):
    out = tmp_path / "grow.html"
    code, err = cli(["render", str(small_run), "--body", "phase:0", "--body", "final", "-o", str(out)], capsys)
    assert code == 0, err
    page = out.read_text()
    assert "<script" not in page and "http://" not in page and "https://" not in page and "<link" not in page
    gif = base64.b64decode(re.search(r'src="data:image/gif;base64,([^"]+)"', page).group(1))
    image = Image.open(io.BytesIO(gif))
    assert image.size[0] == 2 * 320  # two tiles
    assert "phase 0" in page and "final" in page and "gear 0.7" in page  # human starts at 0.7


def test_an_mp4_holds_the_frames_at_the_environment_s_rate(small_run, tmp_path, capsys):
    import imageio.v3 as iio

    out = tmp_path / "best.mp4"
    code, err = cli(["render", str(small_run), "-o", str(out), "--size", "160x120"], capsys)
    assert code == 0, err
    frames = iio.imread(out)
    metadata = iio.immeta(out)
    assert frames.ndim == 4 and frames.shape[0] >= 2 and frames.shape[2] == 160
    assert metadata["fps"] == pytest.approx(1000 / (gaits.frame_stride(0.008) * 8))


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--cell", "9999"], "has cells 0 to"),
        (["--cell", "abc"], "give `best` or a cell index"),
        (["--body", "phase:99"], "the run has phases 0 to"),
        (["--body", "0,1"], "factor(s) above 0"),
        (["--at", "0.5"], "descriptors have 2 value(s)"),
        (["-o", "gait.avi"], "one of .gif, .mp4, .html"),
    ],
)
def test_bad_choices_are_one_message_and_exit_2(small_run, tmp_path, capsys, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    code, err = cli(["render", str(small_run), *args], capsys)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err


def test_an_empty_cell_names_the_best_one(small_run, capsys):
    archive = load_archive(small_run)
    empty = int(np.flatnonzero(~archive.filled)[0])
    code, err = cli(["render", str(small_run), "--cell", str(empty)], capsys)
    assert code == 2 and "is empty" in err and f"in {archive.best_cell}" in err, err


def test_a_missing_run_or_a_folder_of_runs_is_refused(tmp_path, small_run, capsys):
    code, err = cli(["render", str(tmp_path / "nowhere")], capsys)
    assert code == 2 and "no such run directory" in err
    code, err = cli(["render", str(small_run.parent)], capsys)
    assert code == 2 and "give one of them" in err and str(small_run.name) in err


def test_no_gl_backend_names_the_packages_to_install(small_run, capsys, monkeypatch):
    monkeypatch.delenv("MUJOCO_GL", raising=False)
    monkeypatch.setattr(gaits, "GL_BACKENDS", ("none-such",))
    code, err = cli(["render", str(small_run), "-o", "unused.gif"], capsys)
    assert code == 2 and "apt-get install" in err and "libosmesa6" in err, err
