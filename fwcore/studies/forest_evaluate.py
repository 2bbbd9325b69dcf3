"""Maps and classes of a forest flight against its truth (fwcore.studies.forest_truth): ground echoes' F1, the
terrain's and canopy height's RMSE, and cover and PAI on blocks.

Rasters meet on the truth's 1 m grid: a map's cell is taken where its centre falls (maps of coarser cells are
compared with the truth averaged over their blocks).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

CANOPY_M = 2.0  # a cell is under canopy where the truth's canopy height is at least this
SMOOTH_M = 1.0  # a canopy cell is smooth where its truth neighbourhood's heights span at most this


@dataclasses.dataclass(frozen=True)
class Raster:
    """Values (rows north to south) with the west and north edges and the cell size of their grid."""

    values: np.ndarray
    west: float
    north: float
    cell: float


def _centres_in(cells: Raster, grid: Raster) -> tuple[np.ndarray, np.ndarray]:
    """The row (per row of `cells`) and column (per column) of `grid` that each of `cells`' centres falls in."""
    h, w = cells.values.shape
    cx = cells.west + (np.arange(w) + 0.5) * cells.cell
    cy = cells.north - (np.arange(h) + 0.5) * cells.cell
    return (np.floor((grid.north - cy) / grid.cell).astype(np.int64),
            np.floor((cx - grid.west) / grid.cell).astype(np.int64))


def on_grid(source: Raster, target: Raster) -> np.ndarray:
    """`source` at the centres of `target`'s cells (nearest cell; NaN outside)."""
    row, col = _centres_in(target, source)
    sh, sw = source.values.shape
    ok = (row[:, None] >= 0) & (row[:, None] < sh) & (col[None, :] >= 0) & (col[None, :] < sw)
    out = source.values[np.clip(row, 0, sh - 1)[:, None], np.clip(col, 0, sw - 1)[None, :]].astype(float)
    return np.where(ok, out, np.nan)


def block_mean(source: Raster, target: Raster) -> np.ndarray:
    """`source` (finer) averaged over each of `target`'s cells (its cells whose centres fall inside)."""
    row, col = _centres_in(source, target)
    th, tw = target.values.shape
    ok = (row[:, None] >= 0) & (row[:, None] < th) & (col[None, :] >= 0) & (col[None, :] < tw) \
        & np.isfinite(source.values)
    index = (row[:, None] * tw + col[None, :])[ok]
    sums = np.bincount(index, weights=source.values[ok], minlength=th * tw)
    counts = np.bincount(index, minlength=th * tw)
    per = (target.cell / source.cell) ** 2
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(counts >= per - 0.5, sums / counts, np.nan).reshape(th, tw)  # whole blocks only


def rmse(error: np.ndarray) -> float:
    error = np.asarray(error, float)
    error = error[np.isfinite(error)]
    return float(np.sqrt(np.mean(error ** 2))) if error.size else math.nan


def terrain_accuracy(dtm: Raster, chm: Raster, truth_dtm: Raster, truth_chm: Raster, truth_roof: Raster,
                     inner: float = 10.0) -> dict[str, float]:
    """DTM RMSE on open cells (no canopy, no roof) and under canopy (truth CHM >= CANOPY_M), CHM RMSE on canopy
    cells, over the map's cells at least `inner` metres inside the cells with echoes (the swath's edge is
    extrapolated, not measured)."""
    t_dtm, t_chm, t_roof = (on_grid(r, dtm) for r in (truth_dtm, truth_chm, truth_roof))
    seen = np.isfinite(chm.values)
    k = max(int(round(inner / dtm.cell)), 0)
    if k:
        from scipy.ndimage import binary_erosion

        seen = binary_erosion(seen, iterations=k)
    open_ = seen & (t_chm == 0) & (t_roof == 0)
    canopy = seen & (t_chm >= CANOPY_M)
    # where the crowns' surface is smooth: the truth's 3 x 3 neighbourhood within SMOOTH_M (no crown edge, no
    # steep flank, where a cell's highest echo and its highest leaf can be metres apart)
    from scipy.ndimage import maximum_filter, minimum_filter

    smooth = canopy & (maximum_filter(np.nan_to_num(t_chm), 3) - minimum_filter(np.nan_to_num(t_chm), 3) <= SMOOTH_M)
    return {"dtm_rmse_open_m": rmse((dtm.values - t_dtm)[open_]),
            "dtm_rmse_canopy_m": rmse((dtm.values - t_dtm)[canopy]),
            "chm_rmse_canopy_m": rmse((chm.values - t_chm)[canopy]),
            "chm_bias_canopy_m": float(np.nanmean((chm.values - t_chm)[canopy])),
            "chm_rmse_smooth_canopy_m": rmse((chm.values - t_chm)[smooth]),
            "open_cells": int(open_.sum()), "canopy_cells": int(canopy.sum()), "smooth_canopy_cells": int(smooth.sum())}


def canopy_accuracy(cover: Raster, pai: Raster, truth_pgap: Raster, truth_pai: Raster, truth_cover: Raster,
                    seen: np.ndarray) -> dict[str, float]:
    """Cover and PAI of blocks (the maps' cells) against the truth averaged over them: cover against L2B's
    definition (1 - the mean gap probability) and against the crowns' projection; PAI's median relative error
    where the truth's PAI is at least 0.5 (where a ratio means something), against the mean PAI and against the
    PAI the mean gap probability means (L2B's estimate of it assumes no clumping, omega 1)."""
    gap = block_mean(truth_pgap, cover)
    t_pai = block_mean(truth_pai, pai)
    crowns = block_mean(truth_cover, cover)
    ok = seen & np.isfinite(gap) & np.isfinite(cover.values)
    dense = ok & (t_pai >= 0.5) & np.isfinite(pai.values)
    with np.errstate(divide="ignore"):
        effective = -np.log(gap) / 0.5
    return {"cover_median_abs_error": float(np.median(np.abs(cover.values - (1 - gap))[ok])),
            "cover_vs_crowns_median_abs_error": float(np.median(np.abs(cover.values - crowns)[ok])),
            "pai_median_relative_error": float(np.median(np.abs(pai.values - t_pai)[dense] / t_pai[dense])),
            "pai_median_bias": float(np.median((pai.values - t_pai)[dense] / t_pai[dense])),
            # the PAI a gap probability means without clumping (-ln(mean Pgap) / G): what L2B's PAI estimates
            "pai_effective_median_relative_error": float(np.median(
                np.abs(pai.values - effective)[dense] / effective[dense])),
            "pai_effective_median_bias": float(np.median((pai.values - effective)[dense] / effective[dense])),
            "blocks": int(ok.sum()), "pai_blocks": int(dense.sum())}


def ground_scores(found_ground: np.ndarray, truth_ground: np.ndarray) -> dict[str, float]:
    """Precision, recall and F1 of the echoes called ground against the truth's ground echoes (both per found
    echo)."""
    f, t = np.asarray(found_ground, bool), np.asarray(truth_ground, bool)
    tp, fp, fn = int((f & t).sum()), int((f & ~t).sum()), int((~f & t).sum())
    return {"precision": tp / max(tp + fp, 1), "recall": tp / max(tp + fn, 1),
            "f1": 2 * tp / max(2 * tp + fp + fn, 1), "ground_echoes": int(t.sum())}
