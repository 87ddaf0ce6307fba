"""A profile read for stratification, with rLakeAnalyzer's definitions (Read et al. 2011).

- `density`: water density from temperature (fresh water);
- `thermocline`: the thermocline depth, seasonal and not (`thermo.depth`);
- `metalimnion`: the metalimnion's top and bottom (`meta.depths`);
- `schmidt`: Schmidt stability from a profile and the lake's hypsography
  (`schmidt.stability`);
- `features`: what the reference does not define and limnologists read anyway:
  the deep chlorophyll maximum, the oxycline, the top of the hypoxic water, and a
  profile's surface and bottom values.

Each function takes plain arrays (depths in metres, positive down; temperature in
°C) and answers NaN, or None with a reason, where the profile holds no answer:
never a number that is not one. The reference's own quirks are kept where they
change an answer, and said in the docstring: the tests hold our numbers to the
reference's to 1e-6 on its example data and on our profiles
(tests/fixtures/rlakeanalyzer/).
"""
