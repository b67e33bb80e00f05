"""Where each elite of a finished run is put in a batch to be scored again: in its own lane.

A batch's elites are scored together, and which lane of the batch an elite is in is part of
the computation XLA compiles: an elite scored in the lane where it was scored in training
(archive.npz's `lanes`) gets the archive's fitness bit for bit, elsewhere only to float
rounding. `lane_batches` packs cells into as few batches as their lanes allow, and
`lane_index` lays one batch out (a free lane repeats a real elite, so that every lane scores
a real policy); replaying gaits and measuring robustness both go through them.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def lane_batches(cells: Sequence[int], lanes: np.ndarray | None, batch_size: int) -> list[dict[int, int]]:
    """The cells packed into batches, each a {lane: cell}: every cell in its own lane
    (`lanes[cell]`) where it is known (>= 0 and in the batch), the others in free lanes;
    no more batches than needed for the cells that share a lane."""
    batches: list[dict[int, int]] = []
    loose = []
    for cell in dict.fromkeys(int(c) for c in cells):
        lane = int(lanes[cell]) if lanes is not None else -1
        if not 0 <= lane < batch_size:
            loose.append(cell)
            continue
        batch = next((b for b in batches if lane not in b), None)
        if batch is None:
            batch = {}
            batches.append(batch)
        batch[lane] = cell
    for cell in loose:
        batch = next((b for b in batches if len(b) < batch_size), None)
        if batch is None:
            batch = {}
            batches.append(batch)
        batch[next(lane for lane in range(batch_size) if lane not in batch)] = cell
    return batches


def lane_index(batch: dict[int, int], batch_size: int) -> tuple[np.ndarray, np.ndarray]:
    """One batch of `lane_batches` laid out: (batch_size,) the cell scored in every lane (a
    free lane repeats the batch's first cell) and whether the lane holds a cell of its own."""
    first = next(iter(batch.values()))
    index = np.asarray([batch.get(lane, first) for lane in range(batch_size)], dtype=np.int64)
    valid = np.asarray([lane in batch for lane in range(batch_size)], dtype=bool)
    return index, valid


def lane_chunks(
    cells: Sequence[np.ndarray], lanes: Sequence[np.ndarray | None], batch_size: int
) -> list[tuple[np.ndarray, np.ndarray]]:
    """The cells of several runs scored together (one program's positions), each elite in
    its lane: per batch, the cells scored and which are real, both (positions, batch_size);
    a run with fewer batches than another scores its cell 0 in the rest, unused."""
    per_position = [lane_batches(own, own_lanes, batch_size) for own, own_lanes in zip(cells, lanes, strict=True)]
    chunks = []
    for number in range(max(len(batches) for batches in per_position)):
        index = np.zeros((len(per_position), batch_size), dtype=np.int64)
        valid = np.zeros((len(per_position), batch_size), dtype=bool)
        for position, batches in enumerate(per_position):
            if number < len(batches):
                index[position], valid[position] = lane_index(batches[number], batch_size)
        chunks.append((index, valid))
    return chunks
