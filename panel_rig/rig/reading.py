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
    tip_w_m: float  # what the tip sensor reads (noise, resolution, bandwidth, latency; the truth if perfect)
    tip_w_over_L: float  # the model's truth, as q (tip_displacement/truth = tip_w_over_L * L)
    q: np.ndarray
    qdot_per_s: np.ndarray
    aero_force_npm: np.ndarray
    state: str = "running"


@dataclass(frozen=True)
class ReadingBlock:
    """Consecutive samples of the rig as arrays (leading axis = sample), from one block of physics steps."""

    time_s: np.ndarray
    airspeed_mps: np.ndarray
    shaker_force_npm: np.ndarray
    tip_w_m: np.ndarray
    tip_w_over_L: np.ndarray
    q: np.ndarray
    qdot_per_s: np.ndarray
    aero_force_npm: np.ndarray
    state: str = "running"

    def __len__(self) -> int:
        return int(self.time_s.shape[0])

    def readings(self) -> list[Reading]:
        """One :class:`Reading` per sample."""
        return [
            Reading(float(self.time_s[i]), float(self.airspeed_mps[i]), float(self.shaker_force_npm[i]),
                    float(self.tip_w_m[i]), float(self.tip_w_over_L[i]), self.q[i].copy(), self.qdot_per_s[i].copy(),
                    self.aero_force_npm[i].copy(), self.state)
            for i in range(len(self))
        ]

    @staticmethod
    def of(readings: list[Reading]) -> ReadingBlock:
        """Stack single readings (the state of the last one)."""
        def col(name: str) -> np.ndarray:
            return np.array([getattr(r, name) for r in readings], dtype=float)

        return ReadingBlock(col("time_s"), col("airspeed_mps"), col("shaker_force_npm"), col("tip_w_m"),
                            col("tip_w_over_L"), col("q"), col("qdot_per_s"), col("aero_force_npm"),
                            readings[-1].state if readings else "running")


class SinkStop(Exception):
    """Raised by a sink whose failure must end the run that feeds it (a flutter test's recording that can no
    longer be kept: its points would not replay). The rig lets it through; any other error of a sink is logged
    and counted, and the rig goes on (a viewer must not stop the tunnel)."""


class Sink(Protocol):
    """Anything the rig feeds: a ROS publisher set, a bag recorder, a Rerun logger. A sink's errors never stop the
    rig, except :class:`SinkStop`."""

    def on_reading(self, reading: Reading) -> None: ...

    # optional: ``on_block(block: ReadingBlock)`` takes a whole block at once (else on_reading per sample)

    def on_command(self, name: str, value: float, accepted: bool, time_s: float) -> None: ...

    def close(self) -> None: ...
