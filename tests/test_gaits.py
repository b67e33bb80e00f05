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

from smol_dsl.results import gait_video, gaits
from smol_dsl.rundir import load_archive

STEPS = 30  # past the episode (20 steps); every --steps here is this one, one drawing program
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
    assert "<h1>walker2d on spring under" in page and "final body · spring" in page  # the title and the tiles' labels


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
        (["--body", "1.2", "--body", "1.2"], "--body 1.2 is given twice"),
        (["--body", "1e30"], "above what walker2d's physics takes"),
        (["--at", "nan,nan"], "give finite descriptor values"),
        (["--at", "inf,0"], "give finite descriptor values"),
        (["--cells", "1000"], "give --cells"),
        (["-o", "/proc/x.gif"], "cannot write /proc/x.gif"),
        (["--body", "1", "--body", "1.1", "--size", "4096x4096", "--steps", "1000"], "GiB of memory"),
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
    (tmp_path / "notes.md").write_text("a file")
    code, err = cli(["render", str(tmp_path / "notes.md")], capsys)
    assert code == 2 and "is a file, not a run directory" in err
    code, err = cli(["render", str(small_run.parent)], capsys)
    assert code == 2 and "give one of them" in err and str(small_run.name) in err


def test_no_gl_backend_names_the_packages_to_install(small_run, capsys, monkeypatch):
    monkeypatch.delenv("MUJOCO_GL", raising=False)
    monkeypatch.setattr(gaits, "GL_BACKENDS", ("none-such",))
    code, err = cli(["render", str(small_run), "-o", "unused.gif"], capsys)
    assert code == 2 and "apt-get install" in err and "libosmesa6" in err, err


def test_an_mp4_without_the_video_extra_is_refused_before_rendering(small_run, tmp_path, capsys, monkeypatch):
    import importlib.util

    find_spec = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "imageio_ffmpeg" else find_spec(name, *a)
    )
    monkeypatch.setattr(gaits, "render_gaits", lambda *a, **k: pytest.fail("rendered before the check"))
    code, err = cli(["render", str(small_run), "-o", str(tmp_path / "g.mp4")], capsys)
    assert code == 2 and "smol-dsl[video]" in err and not (tmp_path / "g.mp4").exists(), err


def test_canvases_too_large_are_refused_and_many_tiles_make_a_grid():
    assert gait_video.check_canvas(4, 1, (320, 240), 30, 0.008, ".gif") == (2 * 320, 2 * (240 + gait_video.BANNER))
    assert gait_video.check_canvas(110, 1, (640, 16), 30, 0.008, ".gif") == (11 * 640, 10 * (16 + gait_video.BANNER))
    with pytest.raises(gaits.RenderError, match=r"over \.gif's largest side"):
        gait_video.check_canvas(1, 17, (4096, 16), 30, 0.008, ".gif")
    with pytest.raises(gaits.RenderError, match="GiB of memory"):
        gait_video.check_canvas(4, 2, (1024, 1024), 20_000, 0.008, ".mp4")


def test_two_bodies_are_two_rollouts_in_a_frame_of_any_height(small_run, tmp_path, capsys):
    """--body 0.6 --body 1.4: each tile is rolled out in its own body (they differ), at a
    size taller than MuJoCo's default framebuffer."""
    out = tmp_path / "two.gif"
    code, err = cli(
        [
            "render",
            str(small_run),
            "--body",
            "0.6",
            "--body",
            "1.4",
            "--size",
            "320x481",
            "--steps",
            str(STEPS),
            "-o",
            str(out),
        ],
        capsys,
    )
    assert code == 0, err
    frames, _ = gif_frames(out)
    assert frames[0].shape == (481 + gait_video.BANNER, 2 * 320, 3)
    left, right = frames[-1][gait_video.BANNER :, :320], frames[-1][gait_video.BANNER :, 320:]
    assert np.abs(left - right).mean() > 0.5  # not one rollout drawn twice


def test_a_point_outside_the_descriptor_space_is_noted(small_run, tmp_path, capsys):
    from smol_dsl.cli import main

    assert main(["render", str(small_run), "--at", "5,5", "--steps", str(STEPS), "-o", str(tmp_path / "far.gif")]) == 0
    printed = capsys.readouterr().out
    assert "note: --at 5,5 lies outside walker2d's descriptor space ([0, 1] x [0, 1])" in printed, printed
    assert "the nearest elite, in cell" in printed
