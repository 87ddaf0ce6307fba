"""How a single-beam echosounder errs under way: the readings a real survey has to clean.

This module owns the simulated errors of an echosounder on a moving boat, each
as a field survey meets it:
- a second echo: the sound that went to the bed, back to the surface and down
  again, read at twice the distance;
- shallow returns: fish, weed or a thermocline's scatter, read short of the bed;
- dropouts: no echo at all (distance 0, confidence 0, as a Ping1D reports one);
- heave: the boat rising and falling a few centimetres on the waves;
- a confidence that drops when the reading is bad (not always below any
  threshold: a quality control cannot rely on the confidence alone).

Every reading says what it is (`EchoKind`): the truth the tests and benchmarks
check a quality control against; the journal only ever sees the distance and the
confidence. Pure: the randomness comes from the `random.Random` the caller owns
and the time from the caller. It never reads a clock or does I/O.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass
from enum import StrEnum

__all__ = ["EchoErrors", "EchoKind", "Reading", "read"]


class EchoKind(StrEnum):
    GOOD = "good"
    SECOND_ECHO = "second echo"
    SHALLOW = "shallow return"
    DROPOUT = "dropout"

    @property
    def outlier(self) -> bool:
        """A reading with a distance that is not the bed's (a dropout has none)."""
        return self in (EchoKind.SECOND_ECHO, EchoKind.SHALLOW)


@dataclass(frozen=True, slots=True)
class EchoErrors:
    """The rates and sizes of the errors (probabilities per reading, metres, seconds)."""

    outlier_rate: float = 0.03  # half second echoes, half shallow returns
    dropout_rate: float = 0.03
    heave_m: float = 0.03  # amplitude of the boat's rise and fall
    heave_period_s: float = 4.0
    noise_m: float = 0.02  # one standard deviation, clipped at three

    def __post_init__(self) -> None:
        for name in ("outlier_rate", "dropout_rate"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name}={getattr(self, name)} is invalid: allowed 0..1")
        if self.outlier_rate + self.dropout_rate > 1.0:
            raise ValueError("outlier_rate + dropout_rate must not exceed 1")
        if self.heave_m < 0 or self.noise_m < 0 or self.heave_period_s <= 0:
            raise ValueError("heave_m and noise_m must be >= 0, heave_period_s > 0")


@dataclass(frozen=True, slots=True)
class Reading:
    distance_m: float  # from the transducer; 0.0: no echo
    confidence_pct: int
    kind: EchoKind


def heave_m(t_s: float, errors: EchoErrors) -> float:
    """The transducer's rise above its mean depth at `t_s` (metres, up positive)."""
    return errors.heave_m * math.sin(2 * math.pi * t_s / errors.heave_period_s)


def read(
    distance_m: float, confidence_pct: float, t_s: float, rng: random.Random, errors: EchoErrors
) -> Reading:
    """What the echosounder says under way with the bed `distance_m` below the transducer's
    mean depth, where a good echo has `confidence_pct`, at time `t_s`."""
    u = rng.random()
    if u < errors.dropout_rate:
        return Reading(0.0, 0, EchoKind.DROPOUT)
    noise_m = max(-3 * errors.noise_m, min(3 * errors.noise_m, rng.gauss(0.0, errors.noise_m)))
    # The boat up by h: the bed is h farther from the transducer.
    measured = distance_m + heave_m(t_s, errors) + noise_m
    if u < errors.dropout_rate + errors.outlier_rate:
        if rng.random() < 0.5:
            return Reading(max(2.0 * measured, 0.0), rng.randint(25, 75), EchoKind.SECOND_ECHO)
        short = rng.uniform(0.25, 0.85) * distance_m
        return Reading(short, rng.randint(20, 70), EchoKind.SHALLOW)
    return Reading(max(measured, 0.0), max(0, min(100, round(confidence_pct))), EchoKind.GOOD)
