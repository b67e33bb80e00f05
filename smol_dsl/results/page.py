"""index.html, the report's page: the table, what ran, the figures and the gaits, every
image and link a file beside it, so the page works offline and when the folder is moved."""

from __future__ import annotations

import html
from collections.abc import Sequence
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from smol_dsl.results.statistics import PValueTable


def index_page(
    table: PValueTable,
    caption: str,
    figures: Sequence[tuple[str, str]],
    gaits: Sequence[tuple[str, bytes, str]],
    described: Sequence[tuple[str, str]] = (),
    compared_with_paper: bool = False,
    robustness: str = "",
    phase_maps: str = "",
) -> bytes:
    """index.html: the table, what ran (`runs_described`), the figures (stem, caption) and
    the gaits, every image and link a file beside it (no script, style sheet or font from
    anywhere; the phase maps' slider is a script in the page); `robustness`, the robustness
    section's HTML, and `phase_maps`, the archives through the phases, after the figures."""
    esc = html.escape
    images = "\n".join(
        f'<figure id="{esc(stem)}"><img src="{esc(stem)}.png" alt="{esc(text)}" style="max-width: 100%">'
        f'<figcaption>{esc(text)} (<a href="{esc(stem)}.pdf">PDF</a>)</figcaption></figure>'
        for stem, text in figures
    )
    moving = "\n".join(
        f'<figure><img src="{esc(name)}" alt="{esc(text)}"><figcaption>{esc(text)}</figcaption></figure>'
        for name, _, text in gaits
    )
    notes = "".join(f"<li>{esc(note)}</li>" for note in table.notes())
    ran = "".join(f"<li><b>{esc(heading)}</b>: {esc(text)}</li>" for heading, text in described)
    links = [
        '<a href="table.md">table.md</a>',
        '<a href="pvalues.tex">pvalues.tex</a>',
        '<a href="scores.csv">scores.csv</a>',
    ]
    if compared_with_paper:
        links += [
            '<a href="paper-comparison.md">paper-comparison.md</a> (these p-values beside the paper\'s)',
            '<a href="paper-comparison.tex">paper-comparison.tex</a>',
        ]
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{esc(table.task)}: smol-dsl report</title></head>
<body style="font-family: sans-serif; max-width: 1400px">
<h1>{esc(table.task)}: final {esc(table.metric.replace("_", " "))}</h1>
<p>{esc(caption)}</p>
{table.html()}
{f"<ul>{notes}</ul>" if notes else ""}
<h2>What ran</h2>
<ul id="what-ran">{ran}</ul>
<h2>Figures</h2>
{images}
{phase_maps}
{robustness}
{f"<h2>Gaits</h2>{moving}" if gaits else ""}
<p>Also here: {", ".join(links)}.</p>
</body></html>
"""
    return page.encode("utf-8")
