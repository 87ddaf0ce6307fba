"""The lake floor from single-beam soundings: clean them, grid them, say how far to trust it.

Pure, as the whole science floor is: arrays of positions (metres, projected) and
depths (metres below the water surface) in, arrays out; no journal, file, clock
or device. Each step is one module, in the order a map is made:

- `qc`: the quality control, each rejection with its reason (no echo, flagged
  invalid, low confidence, a spike against its along-track neighbours, a
  position jump);
- `spacing`: the survey's line spacing read from its track, and the rules that
  follow from it (cell size, maximum distance, cross-validation blocks);
- `blocks`: the block median at the cell size;
- `interpolate`: the interpolators compared (scipy's, on the block medians);
- `grid`: the gridded bed, its cells farther than the maximum distance from any
  sounding left empty, with each cell's distance to the nearest sounding;
- `validation`: block k-fold cross-validation on held-out whole blocks;
- `contours`: contour lines of the grid (contourpy).

The hypsography of a grid is `science.hypsography.Hypsography.from_depths`.
"""
