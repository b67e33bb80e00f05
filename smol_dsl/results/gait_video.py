"""Gait videos: rendered gaits (`smol_dsl.results.gaits.Gait`) tiled side by side, each
tile labelled with its cell, body, physics and fitness (several elites, or one elite in several
bodies), and written by `write_gaits` as a GIF (Pillow), an MP4 (imageio's bundled ffmpeg,
the `video` extra) or one self-contained web page (the GIF embedded, no script or style from
the network). `check_canvas` refuses, before anything is rolled out, a tiling too large for
its format or for memory; `check_output` an output file no writer here can write.
"""

from __future__ import annotations

import base64
import html
import io
import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from smol_dsl.results.gaits import RenderError, frame_stride
from smol_dsl.rundir.files import atomic_write, check_output_file

if TYPE_CHECKING:
    from smol_dsl.results.gaits import Gait

VIDEO_FORMATS = (".gif", ".mp4", ".html")
MP4_NEEDS = "writing .mp4 needs imageio and its ffmpeg: pip install 'smol-dsl[video]' (or write .gif or .html)"
BANNER = 28  # pixels above each tile: its label, two lines of the default bitmap font
MAX_SIDE = {".gif": 65_535, ".html": 65_535, ".mp4": 16_384}  # GIF's 16-bit sides; H.264's largest frame
MAX_FRAME_BYTES = 2 * 1024**3
"""The most memory the frames of one render may take (the tiles and the tiled images)."""


def grid(tiles: int, bodies: int) -> tuple[int, int]:
    """(rows, columns) of the tiles: one row per elite with its bodies side by side when
    there are several bodies, else a near-square grid of the elites."""
    columns = bodies if bodies > 1 else math.ceil(math.sqrt(tiles))
    return math.ceil(tiles / columns), columns


def check_canvas(
    cells: int, bodies: int, size: tuple[int, int], steps: int, step_seconds: float, suffix: str
) -> tuple[int, int]:
    """Refuse (RenderError), before anything is rolled out, a render whose tiled image is
    too large for its format or whose frames would take more than MAX_FRAME_BYTES; returns
    the image's (width, height)."""
    rows, columns = grid(cells * bodies, bodies)
    width, height = columns * size[0], rows * (size[1] + BANNER)
    most = MAX_SIDE[suffix.lower()]
    if max(width, height) > most:
        raise RenderError(
            f"{cells * bodies} tile(s) of {size[0]}x{size[1]} make a {width}x{height} image, over {suffix}'s largest "
            f"side of {most} pixels; render fewer --cells or a smaller --size"
        )
    frames = steps // frame_stride(step_seconds) + 1
    needed = 2 * frames * width * height * 3
    if needed > MAX_FRAME_BYTES:
        raise RenderError(
            f"{frames} frames of {width}x{height} pixels would take {needed / 1024**3:.1f} GiB of memory (at most "
            f"{MAX_FRAME_BYTES / 1024**3:.0f}); render fewer --cells, a smaller --size or fewer --steps"
        )
    return width, height


def tiled_frames(gaits: Sequence[Gait]) -> list[np.ndarray]:
    """The gaits in a grid (`grid`: an elite's bodies side by side), each under its label;
    a gait whose episode ended early holds its last frame."""
    from PIL import Image, ImageDraw

    length = max(len(g.frames) for g in gaits)
    height, width = gaits[0].frames[0].shape[:2]
    bodies = sum(1 for gait in gaits if gait.cell == gaits[0].cell)  # gaits come elite by elite
    rows, columns = grid(len(gaits), bodies)
    labels = []
    for gait in gaits:
        strip = Image.new("RGB", (width, BANNER), (255, 255, 255))
        for line, text in enumerate(gait.label_lines):
            ImageDraw.Draw(strip).text((3, 2 + 12 * line), _fit(text, width), fill=(0, 0, 0))
        labels.append(np.asarray(strip))
    blank = np.zeros((BANNER + height, width, 3), dtype=np.uint8)
    frames = []
    for index in range(length):
        tiles = [np.concatenate([label, g.frames[min(index, len(g.frames) - 1)]]) for g, label in zip(gaits, labels)]
        tiles += [blank] * (rows * columns - len(tiles))
        frames.append(
            np.concatenate([np.concatenate(tiles[r * columns : (r + 1) * columns], axis=1) for r in range(rows)])
        )
    return frames


def _fit(text: str, width: int) -> str:
    most = max(2, (width - 4) // 6)  # the default bitmap font is ~6 px a character
    return text if len(text) <= most else text[: most - 1] + "…"


def gif_bytes(gaits: Sequence[Gait]) -> bytes:
    from PIL import Image

    frames = [Image.fromarray(frame) for frame in tiled_frames(gaits)]
    out = io.BytesIO()
    frames[0].save(
        out, format="GIF", save_all=True, append_images=frames[1:], duration=gaits[0].frame_ms, loop=0, optimize=False
    )
    return out.getvalue()


def mp4_bytes(gaits: Sequence[Gait]) -> bytes:
    try:
        import imageio.v2 as imageio
    except ImportError:
        raise RenderError(MP4_NEEDS) from None
    import tempfile

    frames = tiled_frames(gaits)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "gait.mp4"
        writer = imageio.get_writer(
            path, fps=1000.0 / gaits[0].frame_ms, codec="libx264", macro_block_size=2, pixelformat="yuv420p"
        )
        try:
            for frame in frames:
                writer.append_data(_even(frame))
        finally:
            writer.close()
        return path.read_bytes()


def _even(frame: np.ndarray) -> np.ndarray:
    """Cropped to even dimensions (H.264 in yuv420p needs them)."""
    return frame[: frame.shape[0] // 2 * 2, : frame.shape[1] // 2 * 2]


def html_page(gaits: Sequence[Gait], title: str) -> bytes:
    """One web page that needs nothing but itself: the gaits as an embedded GIF and a table."""
    gif = base64.b64encode(gif_bytes(gaits)).decode("ascii")
    rows = "\n".join(
        "<tr>"
        + "".join(
            f"<td>{html.escape(str(value))}</td>"
            for value in (
                gait.cell,
                gait.body_label,
                ", ".join(f"{k} {v:.4g}" for k, v in gait.body.items()),
                f"{gait.fitness:.4f}",
                f"{gait.archive_fitness:.4f}",
                ", ".join(f"{x:.3f}" for x in gait.descriptor),
            )
        )
        + "</tr>"
        for gait in gaits
    )
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title></head>
<body style="font-family: sans-serif">
<h1>{html.escape(title)}</h1>
<p><img src="data:image/gif;base64,{gif}" alt="{html.escape("; ".join(g.label for g in gaits))}"></p>
<table border="1" cellpadding="4" style="border-collapse: collapse">
<tr><th>cell</th><th>body</th><th>factors</th><th>fitness (this body)</th><th>archive fitness (final body)</th>
<th>descriptor</th></tr>
{rows}
</table>
<p>{max(len(gait.frames) for gait in gaits)} frames of {gaits[0].frame_ms:.0f} ms (real time).</p>
</body></html>
"""
    return page.encode("utf-8")


def check_output(out: str | Path) -> Path:
    """-o's file: its suffix names a format whose writer is installed, and its folder
    exists and can be written."""
    path = check_output_file(out, VIDEO_FORMATS, "gait.gif", RenderError)
    if path.suffix.lower() == ".mp4":
        import importlib.util

        if importlib.util.find_spec("imageio") is None or importlib.util.find_spec("imageio_ffmpeg") is None:
            raise RenderError(MP4_NEEDS)
    return path


def write_gaits(out: str | Path, gaits: Sequence[Gait], title: str = "gaits") -> Path:
    """The gaits side by side into `out`, the format by its suffix (.gif, .mp4, .html),
    written whole or not at all."""
    path = check_output(out)
    suffix = path.suffix.lower()
    data = gif_bytes(gaits) if suffix == ".gif" else mp4_bytes(gaits) if suffix == ".mp4" else html_page(gaits, title)
    atomic_write(path, lambda file: file.write(data))
    return path
