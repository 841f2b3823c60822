"""What the rig hands to its sinks (topics, bag, Rerun) after each published tick."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np


@dataclass(frozen=True)
class Reading:
    """One sample of the rig, SI units, stamped with the rig's simulated time."""

    time_s: float
    airspeed_mps: float
    shaker_force_npm: float
    tip_w_m: float
    tip_w_over_L: float
    q: np.ndarray
    qdot_per_s: np.ndarray
    aero_force_npm: np.ndarray
    state: str = "running"


class Sink(Protocol):
    """Anything the rig feeds: a ROS publisher set, a bag recorder, a Rerun logger."""

    def on_reading(self, reading: Reading) -> None: ...

    def on_command(self, name: str, value: float, accepted: bool, time_s: float) -> None: ...

    def close(self) -> None: ...
