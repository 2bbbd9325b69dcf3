"""Terrain and canopy from classified echoes: the ground filter (ground), terrain models by interpolation
(dtm), ASPRS classes and heights above the terrain (classes), canopy and surface models (canopy), and the
tiles with overlap that let a survey of any size stream through them (tiles)."""
