"""A sonde's cast made into profiles, as CTD software does it (docs/profiles.md).

- `casts`: the way down split from the way up by the winch's motion, and the loop
  edit (readings taken while the probe stood still or rose on its way, the
  surface soak, water sampled twice);
- `lag`: each sensor's first-order lag corrected (or, to compare, a time shift);
- `binning`: averages on depth bins with their count and standard deviation, and
  the bins with too few readings flagged;
- `process`: the whole of it for one cast, arrays in, two binned profiles out.

Pure: time, depth and values arrive as arrays (NaN for a missing value); nothing
here reads a journal, a clock or a file.
"""
