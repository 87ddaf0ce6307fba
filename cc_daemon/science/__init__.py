"""The science floor: profiles read for stratification and the lake floor mapped.

Pure: arrays in, arrays out (numpy), with the field's definitions and units in
each function's docstring. It reads no journal, file, clock or device and imports
nothing of the project: the export and command floors hand it arrays and write
what it gives back. The daemon never imports it (an import-linter contract), so
its libraries stay an extra of the laptop and the Pi's data tools, never of the
service.

- `hypsography`: a lake's area and volume at each depth, the one value the two
  halves share (the bathymetry makes it; Schmidt stability reads it).
- `profiles`: a sonde's cast made into binned, lag-corrected profiles, and what is
  read from them (docs/profiles.md).
- `limnology`: rLakeAnalyzer's definitions (density, thermocline, metalimnion,
  Schmidt stability) and the chlorophyll and oxygen features.
- `interpolation`: R's linear interpolation and sequences, as the reference uses them.
"""
