"""The explorer's page: one HTML file with its script and style inline (no request leaves
the server), drawing each run's archive on a canvas with a slider over its phases, the
coverage, max-fitness and α curves (the body each generation trained in) with the moment marked, another run's archive beside it at the
same moment on one colour scale (schedules side by side), and, for a clicked cell, the final
archive's elite rendered in the bodies chosen. The view (run, moment, cell, the run beside) is
kept in the URL's fragment, so a view can be shared; arrow keys step through the moments,
space plays them. The script reads the server's token from the page's URL (`?token=`) and
sends it with every request (`explorer_app`); its hash (`SCRIPT_HASH`) is what the page's
Content-Security-Policy lets run."""

from __future__ import annotations

import base64
import hashlib

PAGE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>smol-dsl explore</title><link rel="icon" href="data:,">
<style>
body { font-family: sans-serif; margin: 1em; max-width: 1300px }
#main { display: flex; gap: 1.5em; flex-wrap: wrap }
canvas { border: 1px solid #ccc; cursor: crosshair }
#controls { margin: .5em 0 }
#slider { width: 420px; vertical-align: middle }
#cell-info { min-width: 320px; max-width: 520px }
#status { color: #555 } .error { color: #b00 }
</style></head>
<body>
<h1>smol-dsl explore</h1>
<p>A run's archive at the start and end of each phase; click a cell for the final archive's elite in it, rolled out in
the bodies ticked (the same rollout as <code>smol-dsl render</code>); pick another run to see beside it at the same moment,
on one colour scale. Keys: left and right step, space plays.</p>
<p id="problem" class="error" hidden></p>
<label>run <select id="run"></select></label>
<label>beside it <select id="beside"><option value="">no other run</option></select></label>
<div id="main">
 <div id="left" style="width: 540px">
  <canvas id="map" width="520" height="520" aria-label="archive map"></canvas>
  <div id="controls"><input type="range" id="slider" min="0" max="0" value="0" aria-label="moment">
   <button type="button" id="play">play</button><br><span id="moment"></span><br><small id="view"></small></div>
  <canvas id="curve" width="600" height="170" aria-label="coverage, max fitness and alpha"></canvas>
 </div>
 <div id="right" style="width: 540px" hidden>
  <canvas id="map-beside" width="520" height="520" aria-label="the other run's archive map"></canvas>
  <p id="moment-beside"></p>
 </div>
 <div id="cell-info">
  <p>bodies: <label><input type="checkbox" id="body-final" checked> final</label>
   <label><input type="checkbox" id="body-child" checked> the child: phase
   <input type="number" id="child-phase" value="0" min="0" style="width: 4em"></label></p>
  <p id="status">click a filled cell</p>
  <p id="fitness"></p>
  <img id="gait" alt="" hidden>
 </div>
</div>
<script>
(() => {
const $ = (id) => document.getElementById(id);
const token = new URLSearchParams(location.search).get("token") || "";
async function ask(path) {  // the server's JSON answer, or an Error with its message
  const reply = await fetch(path, {headers: {"X-Smol-Dsl-Token": token}}), answer = await reply.json();
  if (!reply.ok) throw new Error(answer.error || `${reply.status}`);
  return answer;
}
const problem = (error) => { $("problem").hidden = false; $("problem").textContent = String(error.message || error); };
const state = {runs: [], run: null, data: null, snap: 0, cell: null, timer: null, beside: null, other: null};
const stops = [[68,1,84],[59,82,139],[33,145,140],[94,201,98],[253,231,37]];
const color = (t) => { t = Math.max(0, Math.min(1, t)) * (stops.length - 1); const i = Math.min(stops.length - 2, Math.floor(t));
  const f = t - i, a = stops[i], b = stops[i + 1]; return `rgb(${a.map((v, k) => Math.round(v + f * (b[k] - v))).join(",")})`; };
const hash = () => Object.fromEntries(location.hash.slice(1).split("&").filter(Boolean).map((p) => p.split("=")));
const save = () => { const h = `run=${state.run}&moment=${state.snap}` + (state.cell === null ? "" : `&cell=${state.cell}`) +
  (state.beside === null ? "" : `&beside=${state.beside}`);
  history.replaceState(null, "", "#" + h); };
function position(c, d = state.data, m = $("map")) {
  const pad = 20, w = m.width - 2 * pad, h = m.height - 2 * pad;
  const x = (d.centroids[c][0] - d.low[0]) / (d.high[0] - d.low[0]);
  const y = d.centroids[c].length > 1 ? (d.centroids[c][1] - d.low[1]) / (d.high[1] - d.low[1]) : 0.5;
  return [pad + x * w, pad + (1 - y) * h];
}
function scale() {  // one colour scale for every moment of the run and of the run beside it
  const all = [state.data, state.other].filter(Boolean).flatMap((d) => d.snapshots.flatMap((s) => s.fitnesses).concat(d.final))
    .filter((v) => v !== null);
  return [Math.min(...all), Math.max(...all)];
}
function drawMap(m, d, snap, cell, lo, hi) {  // a run's archive at moment `snap` (its final one if it kept none): what it says
  const g = m.getContext("2d"), s = d.snapshots[snap], fit = s ? s.fitnesses : d.final;
  g.clearRect(0, 0, m.width, m.height);
  const r = Math.max(3, 0.45 * (m.width - 40) / Math.sqrt(d.centroids.length));
  d.centroids.forEach((_, c) => { const [x, y] = position(c, d, m); g.beginPath(); g.arc(x, y, fit[c] === null ? 1.5 : r, 0, 2 * Math.PI);
    g.fillStyle = fit[c] === null ? "#bbb" : color(hi > lo ? (fit[c] - lo) / (hi - lo) : 1); g.fill();
    if (c === cell) { g.lineWidth = 2; g.strokeStyle = "#e00"; g.stroke(); } });
  const filled = fit.filter((v) => v !== null).length;
  const body = s && s.body ? `, body reached ${s.body.map((v) => v.toFixed(3)).join(", ")}` : "";  // a paced run's
  return s ? `phase ${s.phase}, ${s.moment} (generation ${s.generation}): ${filled} cells, coverage ${(100 * filled / fit.length).toFixed(1)}%${body}`
    : `final archive: ${filled} cells`;
}
function draw() {
  const d = state.data, [lo, hi] = scale(), dims = d.centroids[0].length;
  $("moment").textContent = drawMap($("map"), d, state.snap, state.cell, lo, hi);
  $("view").textContent = (dims > 2 ? `cells at descriptors 1 and 2 of ${dims}; ` : dims === 1 ? "cells along the descriptor; " : "") +
    `colour: fitness from ${lo.toFixed(1)} (purple) to ${hi.toFixed(1)} (yellow)` + (state.other ? ", both maps" : "");
  $("right").hidden = !state.other;
  if (state.other) {  // the same moment of the other run (its last if it kept fewer)
    const o = state.other, snap = Math.min(state.snap, Math.max(0, o.snapshots.length - 1));
    $("moment-beside").textContent = `${state.runs[state.beside].label}: ` + drawMap($("map-beside"), o, snap, null, lo, hi);
  }
  drawCurve();
}
function drawCurve() {
  const d = state.data, c = $("curve"), g = c.getContext("2d"), pad = 24, w = c.width - 2 * pad, h = c.height - 2 * pad;
  g.clearRect(0, 0, c.width, c.height);
  const gens = d.generations_per_row, last = Math.max(1, gens[gens.length - 1]), top = Math.max(...d.coverage, 1);
  g.strokeStyle = "#1f77b4"; g.beginPath();
  d.coverage.forEach((v, i) => { const x = pad + w * gens[i] / last, y = pad + h * (1 - v / top); i ? g.lineTo(x, y) : g.moveTo(x, y); });
  g.stroke(); g.fillStyle = "#1f77b4"; g.fillText(`coverage % (0 to ${top.toFixed(1)})`, pad, 14);
  const best = d.max_fitness.filter(v => v !== null);
  if (best.length) {  // max fitness on its own scale, from its lowest to its highest value
    const low = Math.min(...best), high = Math.max(...best), span = high - low || 1;
    g.strokeStyle = "#ff7f0e"; g.beginPath(); let drawn = false;
    d.max_fitness.forEach((v, i) => {
      if (v === null) return;
      const x = pad + w * gens[i] / last, y = pad + h * (1 - (v - low) / span);
      drawn ? g.lineTo(x, y) : g.moveTo(x, y); drawn = true;
    });
    g.stroke(); g.fillStyle = "#ff7f0e"; g.fillText(`max fitness (${low.toFixed(1)} to ${high.toFixed(1)})`, pad + 200, 14);
  }
  const alphas = d.alpha, aLow = Math.min(...alphas), aHigh = Math.max(...alphas), aSpan = aHigh - aLow || 1;
  g.strokeStyle = "#2ca02c"; g.beginPath();  // the body trained in (a paced run's, as its archive let it move on)
  alphas.forEach((v, i) => { const x = pad + w * gens[i] / last, y = pad + h * (1 - (v - aLow) / aSpan); i ? g.lineTo(x, y) : g.moveTo(x, y); });
  g.stroke(); g.fillStyle = "#2ca02c"; g.fillText(`α (${aLow.toFixed(2)} to ${aHigh.toFixed(2)})`, pad + 390, 14);
  g.fillStyle = "#333"; g.fillText("over generations", pad + 470, 14);
  const s = d.snapshots[state.snap];
  if (s) { const x = pad + w * s.generation / last; g.strokeStyle = "#e00"; g.beginPath(); g.moveTo(x, pad); g.lineTo(x, pad + h); g.stroke(); }
}
function setMoment(i) { state.snap = Math.max(0, Math.min(state.data.snapshots.length - 1, i)); $("slider").value = state.snap; draw(); save(); }
function cellAt(x, y) {
  let best = null, dist = Infinity;
  state.data.centroids.forEach((_, c) => { const [cx, cy] = position(c), e = (cx - x) ** 2 + (cy - y) ** 2; if (e < dist) { dist = e; best = c; } });
  return best;
}
async function showCell(c) {
  state.cell = c; draw(); save();
  const bodies = [["body-final", "final"], ["body-child", `phase:${$("child-phase").value || 0}`]].filter(([id]) => $(id).checked).map(([, b]) => b);
  if (state.data.final[c] === null) { $("status").textContent = `cell ${c} is empty in the final archive`; $("gait").hidden = true; return; }
  const started = performance.now(), tick = setInterval(() => { $("status").textContent =
    `rendering cell ${c}... ${((performance.now() - started) / 1000).toFixed(0)} s`; }, 250);
  $("status").className = ""; $("status").textContent = `rendering cell ${c}...`;
  try {
    const query = new URLSearchParams([["cell", c], ...bodies.map((b) => ["body", b])]);
    const answer = await ask(`api/runs/${state.run}/gait?${query}`);
    if (state.cell !== c) return;
    $("gait").src = `${answer.image}?token=${encodeURIComponent(token)}`;
    $("gait").alt = `the elite of cell ${c}`; $("gait").hidden = false;
    $("fitness").textContent = `cell ${c}: archive fitness ${answer.archive_fitness.toFixed(4)}, descriptor ` +
      `(${answer.archive_descriptor.map((v) => v.toFixed(3)).join(", ")}); ` +
      answer.gaits.map((g) => `${g.body} body: fitness ${g.fitness.toFixed(4)}`).join("; ") +
      (answer.gaits[0].inexact ? ` (not replayed in the program that scored the archive: ${answer.gaits[0].inexact}; ` +
        "in the final body the fitness agrees with the archive's to float rounding, not bit for bit)" : "");
    $("status").textContent = answer.cached ? "from the cache" : `rendered in ${answer.seconds} s`;
  } catch (error) { $("status").className = "error"; $("status").textContent = String(error.message || error); }
  finally { clearInterval(tick); }
}
async function loadBeside(number) {
  state.beside = Number.isInteger(number) && state.runs[number] ? number : null;
  state.other = state.beside === null ? null : await ask(`api/runs/${state.beside}`);
  $("beside").value = state.beside === null ? "" : state.beside;
  if (state.data) { draw(); save(); }
}
async function loadRun(number, moment, cell) {
  state.run = number; state.data = await ask(`api/runs/${number}`);
  $("slider").max = Math.max(0, state.data.snapshots.length - 1); $("child-phase").max = state.data.phases - 1;
  state.cell = null; $("gait").hidden = true; $("fitness").textContent = "";
  setMoment(moment === undefined ? state.data.snapshots.length - 1 : moment);
  if (cell !== undefined) await showCell(cell);
}
$("slider").addEventListener("input", () => setMoment(Number($("slider").value)));
$("run").addEventListener("change", () => loadRun(Number($("run").value)).catch(problem));
$("beside").addEventListener("change", () =>
  loadBeside($("beside").value === "" ? null : Number($("beside").value)).catch(problem));
$("map").addEventListener("click", (event) => { const box = $("map").getBoundingClientRect();
  showCell(cellAt((event.clientX - box.left) * $("map").width / box.width, (event.clientY - box.top) * $("map").height / box.height)); });
function play() {
  if (state.timer) { clearInterval(state.timer); state.timer = null; $("play").textContent = "play"; return; }
  if (state.snap >= state.data.snapshots.length - 1) setMoment(0);
  $("play").textContent = "pause";
  state.timer = setInterval(() => { if (state.snap >= state.data.snapshots.length - 1) return play(); setMoment(state.snap + 1); }, 300);
}
$("play").addEventListener("click", play);
document.addEventListener("keydown", (event) => { if (event.target.tagName === "SELECT") return;
  if (event.key === "ArrowLeft") setMoment(state.snap - 1); else if (event.key === "ArrowRight") setMoment(state.snap + 1);
  else if (event.key === " ") { event.preventDefault(); play(); } });
window.explorer = {state, position, showCell, setMoment, loadBeside};
(async () => {
  state.runs = await ask("api/runs");
  state.runs.forEach((r) => { for (const id of ["run", "beside"]) {
    const o = document.createElement("option"); o.value = r.id; o.textContent = r.label; $(id).append(o); } });
  const h = hash(), run = h.run !== undefined ? Number(h.run) : 0;
  $("run").value = run;
  if (h.beside !== undefined) await loadBeside(Number(h.beside));
  await loadRun(run, h.moment !== undefined ? Number(h.moment) : undefined, h.cell !== undefined ? Number(h.cell) : undefined);
  window.explorer.ready = true;
})().catch(problem);
})();
</script>
</body></html>
"""


SCRIPT = PAGE.split("<script>", 1)[1].split("</script>", 1)[0]
SCRIPT_HASH = "sha256-" + base64.b64encode(hashlib.sha256(SCRIPT.encode()).digest()).decode()
"""The inline script's hash, as a Content-Security-Policy's script-src names it."""


def explorer_page() -> str:
    """The page's HTML (script and style inline)."""
    return PAGE
