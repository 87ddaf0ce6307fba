"""How far to trust the map: block k-fold cross-validation on held-out soundings.

The block medians are split into square blocks of `block_m` (half the line
spacing: `spacing`), the blocks shuffled into `folds` folds; each fold in turn is held
out, the bed interpolated from the others and compared with it. Whole blocks are
held out, never single soundings: a sounding's neighbour on the same line, a
metre away, would otherwise predict it almost perfectly and the error reported
would be the noise's, not the map's (verde's `BlockKFold`, for the same reason).
The RMSE and the bias (mean of predicted minus held out) are the map's
cross-validated accuracy, an estimate and said as one. A held-out block median is
itself a measurement, with the noise of the soundings it reduces (its standard
error, from their spread: `blocks`); that part of the residuals is the
measurement's, not the map's, and is taken out of the mean square reported (the
raw figure is kept beside it).

Pure: arrays in, numbers out (numpy).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cc_daemon.science.bathymetry import interpolate
from cc_daemon.science.bathymetry.blocks import Blocks

DEFAULT_FOLDS = 5
MIN_PREDICTED = 20  # fewer held-out medians estimate nothing: the RMSE is NaN then


@dataclass(frozen=True, slots=True)
class CrossValidation:
    rmse_m: float  # NaN when nothing could be predicted
    bias_m: float  # mean of (predicted - held out)
    predicted: int  # held-out block medians the others could predict (inside their hull)
    folds: int
    block_m: float
    raw_rmse_m: float  # before the held-out medians' own noise is taken out


def block_kfold(
    blocks: Blocks,
    *,
    block_m: float,
    folds: int = DEFAULT_FOLDS,
    method: str = interpolate.DEFAULT,
    seed: int = 0,
    max_edge_m: float | None = None,
) -> CrossValidation:
    """Cross-validate `method` on `blocks`, holding out square blocks of `block_m` metres
    `folds` times (seeded: the same answer every time); `max_edge_m` as the grid's."""
    if folds < 2:
        raise ValueError(f"{folds} folds: at least 2")
    group = np.column_stack([np.floor(blocks.x / block_m), np.floor(blocks.y / block_m)]).astype(
        np.int64
    )
    _, which = np.unique(group, axis=0, return_inverse=True)
    which = which.ravel()
    order = np.random.default_rng(seed).permutation(int(which.max()) + 1 if len(which) else 0)
    fold = order[which] % folds
    residuals = []
    noise = []
    for k in range(folds):
        held = fold == k
        train = blocks.take(~held)
        if len(train) < 3 or not held.any():
            continue
        try:
            predict = interpolate.fit(train.x, train.y, train.depth, method, max_edge_m=max_edge_m)
        except ValueError:
            continue
        predicted = predict(blocks.x[held], blocks.y[held])
        residuals.append(predicted - blocks.depth[held])
        noise.append(blocks.noise_m[held])
    found = np.concatenate(residuals) if residuals else np.zeros(0)
    own = np.concatenate(noise) if noise else np.zeros(0)
    usable = np.isfinite(found)
    found, own = found[usable], own[usable]
    if len(found) < MIN_PREDICTED:
        return CrossValidation(float("nan"), float("nan"), len(found), folds, block_m, float("nan"))
    # A held-out median carries its own noise; the map's error is what is left of the
    # residuals' mean square once that is taken out. Never less than the bias: the
    # noise has no mean, so it cannot explain one (an RMSE of 0 beside a bias of
    # 1 cm would claim a perfect map).
    raw = float(np.mean(found**2))
    noise_ms = float(np.mean(own**2))
    bias = float(np.mean(found))
    return CrossValidation(
        float(np.sqrt(max(raw - noise_ms, bias**2))),
        bias,
        len(found),
        folds,
        block_m,
        float(np.sqrt(raw)),
    )
