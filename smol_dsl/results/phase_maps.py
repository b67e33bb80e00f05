"""The report's archive maps through the phases: each schedule's median run's archive at the
start and end of its phases (phases.npz, `smol_dsl.rundir.snapshots`), side by side on one
colour scale, one PNG per moment (`phase_map_frames`), and the slider that steps through them
on the report's page (`phase_maps_html`: a few lines of inline script, every image a file
beside the page).
"""

from __future__ import annotations

import html
import io
import json
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from smol_dsl.results.report_figures import archives_figure
from smol_dsl.rundir import FinalArchive, RunRecord
from smol_dsl.rundir.snapshots import END, Snapshot, SnapshotsError, read_snapshots

MOST_FRAMES = 40
"""Frames at most: a run of more phases is shown at the start and end of evenly spread ones."""
PHASE_MAP_FILES = "phase-maps-*.png"


def frame_name(index: int) -> str:
    return f"phase-maps-{index:03d}.png"


def chosen_moments(snapshots: Sequence[Snapshot], most: int = MOST_FRAMES) -> list[int]:
    """The indices of the snapshots shown: all of them, or the start and end of evenly
    spread phases (the first and the last included) when there are more than `most`."""
    if len(snapshots) <= most:
        return list(range(len(snapshots)))
    phases = sorted({s.phase for s in snapshots})
    kept = {phases[round(k * (len(phases) - 1) / (most // 2 - 1))] for k in range(most // 2)}
    return [index for index, s in enumerate(snapshots) if s.phase in kept]


def moment_label(snapshot: Snapshot) -> str:
    when = "end" if snapshot.moment == END else "start"
    return f"phase {snapshot.phase}, {when} (generation {snapshot.generation})"


@dataclass(frozen=True)
class PhaseMaps:
    """The report's phase maps: one (label, PNG) per moment, and a note for each chosen run
    left out because its phases.npz cannot be read."""

    frames: list[tuple[str, bytes]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def phase_map_frames(chosen: dict[str, RunRecord], low: Sequence[float], high: Sequence[float], task: str) -> PhaseMaps:
    """One PNG per moment of the runs' phases (each schedule's chosen run side by side, one
    colour scale over every frame). A run whose phases.npz is damaged is left out with a
    note (the others are drawn); no frames at all where the rest have no phases.npz or their
    snapshots do not line up (runs from before snapshots were kept)."""
    series, notes = {}, []
    for name, run in chosen.items():
        try:
            series[name] = read_snapshots(run.directory)
        except SnapshotsError as error:
            notes.append(f"the phase maps leave out {name}'s median run (seed {run.seed}): {error}")
    lengths = {len(snapshots) for snapshots in series.values()}
    if not series or 0 in lengths or len(lengths) != 1:
        return PhaseMaps([], notes)
    first = next(iter(series.values()))
    moments = chosen_moments(first)
    filled = [s.fitnesses[s.filled] for snapshots in series.values() for s in snapshots]
    values = np.concatenate(filled) if filled else np.zeros(0)
    scale = (float(values.min()), float(values.max())) if values.size else None
    frames = []
    for index in moments:
        panels = []
        for name, snapshots in series.items():
            snapshot = snapshots[index]
            centroids = chosen[name].final_archive().centroids
            archive = FinalArchive(snapshot.fitnesses, snapshot.descriptors, centroids, snapshot.filled)
            panels.append((name, chosen[name].seed, archive))
        figure = archives_figure(panels, low, high, f"{task}: {moment_label(first[index])}", scale=scale, pixels=160)
        image = io.BytesIO()
        figure.savefig(image, format="png", dpi=80)
        frames.append((moment_label(first[index]), image.getvalue()))
    return PhaseMaps(frames, notes)


def phase_maps_html(labels: Sequence[str], notes: Sequence[str] = ()) -> str:
    """The page's section: the frames (files beside the page) behind a slider and a play
    button, the last frame (the final archives) shown first, and the notes of runs left out."""
    esc = html.escape
    said = "".join(f'\n<p class="note">Note: {esc(note)}</p>' for note in notes)
    if not labels:
        return f'<h2 id="phases">Archives through the phases</h2>{said}' if notes else ""
    last = len(labels) - 1
    return f"""<h2 id="phases">Archives through the phases</h2>
<p>Each schedule's median run, its archive at the start (after the re-evaluation into the phase's body) and at the
end of each phase: the collapse at each change of body and the refill after it.</p>{said}
<figure id="phase-maps"><img id="phase-map" src="{esc(frame_name(last))}" alt="archives at {esc(labels[last])}"
style="max-width: 100%"><figcaption><input type="range" id="phase-slider" min="0" max="{last}" value="{last}"
style="width: 60%" aria-label="moment"> <button type="button" id="phase-play">play</button>
<span id="phase-label">{esc(labels[last])}</span></figcaption></figure>
<script>
(() => {{
  const labels = {json.dumps(list(labels))};
  const slider = document.getElementById("phase-slider"), image = document.getElementById("phase-map");
  const label = document.getElementById("phase-label"), play = document.getElementById("phase-play");
  const show = (i) => {{
    slider.value = i;
    image.src = "phase-maps-" + String(i).padStart(3, "0") + ".png";
    image.alt = "archives at " + labels[i];
    label.textContent = labels[i];
  }};
  slider.addEventListener("input", () => show(Number(slider.value)));
  let timer = null;
  play.addEventListener("click", () => {{
    if (timer) {{ clearInterval(timer); timer = null; play.textContent = "play"; return; }}
    let i = Number(slider.value) >= labels.length - 1 ? 0 : Number(slider.value);
    play.textContent = "pause";
    show(i);
    timer = setInterval(() => {{
      i += 1;
      if (i >= labels.length) {{ clearInterval(timer); timer = null; play.textContent = "play"; return; }}
      show(i);
    }}, 400);
  }});
}})();
</script>"""
