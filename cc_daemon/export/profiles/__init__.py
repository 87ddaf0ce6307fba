"""`cc-daemon profiles`: a survey's profiles and what they say, as files a limnologist publishes.

- `survey`: the journal's readings made into binned, lag-corrected profiles and
  their derived numbers (by `cc_daemon.science`);
- `tables`: the binned profiles as CSV, the stations table as CSV and GeoJSON;
- `netcdf`: the binned profiles as CF NetCDF (`featureType = profile`);
- `castplot`: each cast's binned profiles over its raw readings;
- `sections`: each parameter along the survey against depth, above the bed;
- `hypsography_csv`: the lake's hypsography, for Schmidt stability.

It never reads the journal itself: the command hands it records.
"""
