"""The report's index.html from a real run, opened in headless Chromium: it loads nothing
but the files beside it, logs no error, and shows the table, what ran, the figures (captioned,
with their PDFs) and the gaits."""

from __future__ import annotations

import io

import numpy as np
import pytest
from browser import chromium, visit
from PIL import Image

from smol_dsl.cli import main


@pytest.fixture(scope="module")
def report_dir(small_run, tmp_path_factory):
    out = tmp_path_factory.mktemp("report") / "report"
    assert main(["report", str(small_run), "-o", str(out), "--gaits", "2"]) == 0
    return out


def test_the_report_writes_a_page_and_each_schedule_s_gaits(report_dir):
    gifs = sorted(report_dir.glob("gaits-*.gif"))
    assert [gif.name for gif in gifs] == ["gaits-00-smol-human.gif"]
    image = Image.open(gifs[0])
    assert image.size[0] == 2 * 320 and image.n_frames >= 2  # two elites side by side
    page = (report_dir / "index.html").read_text()
    assert "<script src" not in page and "http" not in page.replace('href="table.md"', "")  # no outside script


def test_the_page_says_what_ran_captions_its_figures_and_links_only_files_beside_it(report_dir):
    import re

    page = (report_dir / "index.html").read_text()
    for heading in ("runs", "budget", "settings", "environment"):
        assert f"<b>{heading}</b>: " in page, heading
    assert "208 evaluations per run" in page and "Python " in page
    captions = re.findall(r"<figcaption>(.*?)</figcaption>", page, re.S)
    assert captions and all(len(caption) > 40 for caption in captions), captions  # sentences, not file names
    links = re.findall(r'href="([^"]+)"', page)
    assert "main-results.pdf" in links and "archives.pdf" in links
    assert all((report_dir / link).is_file() for link in links), links


@pytest.mark.skipif(chromium() is None, reason="no Chromium (Debian: apt-get install chromium; .ci/run installs it)")
def test_the_page_opens_offline_in_chromium_with_everything_decoded(report_dir):
    seen = visit(report_dir / "index.html")
    outside = [url for url in seen.requests if not url.startswith(report_dir.resolve().as_uri())]
    assert not outside, outside  # no request leaves the report's directory
    assert not seen.errors, seen.errors
    assert seen.has_table
    sources = {image["src"] for image in seen.images}
    assert {"main-results.png", "archives.png", "gaits-00-smol-human.gif"} <= sources
    assert all(image["complete"] and image["width"] > 0 for image in seen.images), seen.images
    shot = np.asarray(Image.open(io.BytesIO(seen.screenshot)).convert("L"), dtype=float)
    assert shot.std() > 10  # not blank


def test_no_gaits_renders_nothing(small_run, tmp_path):
    out = tmp_path / "plain"
    assert main(["report", str(small_run), "-o", str(out), "--no-gaits"]) == 0
    assert not list(out.glob("gaits-*.gif"))
    assert "Gaits" not in (out / "index.html").read_text()


SLIDE_TO_THE_FIRST_MOMENT = """(async () => {
  const slider = document.getElementById("phase-slider"), image = document.getElementById("phase-map");
  const before = image.getAttribute("src");
  slider.value = 0;
  slider.dispatchEvent(new Event("input"));
  await new Promise((done) => { if (image.complete) done(); else { image.onload = done; image.onerror = done; } });
  return {before, after: image.getAttribute("src"), width: image.naturalWidth,
          label: document.getElementById("phase-label").textContent};
})()"""


def test_the_page_steps_through_the_median_run_s_phases(report_dir, small_run):
    """The report shows the archive at the start and end of every phase (phases.npz), one
    frame per moment, the final archive first."""
    from smol_dsl.rundir.snapshots import read_snapshots

    frames = sorted(report_dir.glob("phase-maps-*.png"))
    assert len(frames) == len(read_snapshots(small_run)) == 2 * 10
    page = (report_dir / "index.html").read_text()
    assert 'id="phase-slider"' in page and f'src="{frames[-1].name}"' in page and "phase 9, end" in page


@pytest.mark.skipif(chromium() is None, reason="no Chromium (Debian: apt-get install chromium; .ci/run installs it)")
def test_the_phase_slider_changes_the_map_in_chromium(report_dir):
    seen = visit(report_dir / "index.html", script=SLIDE_TO_THE_FIRST_MOMENT)
    assert not seen.errors, seen.errors
    assert seen.result["before"] == "phase-maps-019.png" and seen.result["after"] == "phase-maps-000.png"
    assert seen.result["width"] > 0 and seen.result["label"].startswith("phase 0, start")
    outside = [url for url in seen.requests if not url.startswith(report_dir.resolve().as_uri())]
    assert not outside, outside
