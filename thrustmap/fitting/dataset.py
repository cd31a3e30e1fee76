"""Ds: bench triplets (thrust T, battery voltage B, throttle Th) as loaded from one file."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from thrustmap.core.units import ThrottleScale

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

#: ``Dataset.meta["layout"]`` of an export with one averaged row per throttle step.
STEP_SUMMARY = "step-summary"
#: ``Dataset.meta["thrust_sensor"]`` of a stand whose load cell updates every few samples and
#: holds its value in between (the loader knows it from the format).
SAMPLE_AND_HOLD = "sample-and-hold"
#: What each detected layout means, as ``inspect`` says it.
LAYOUTS: dict[str, str] = {
    STEP_SUMMARY: "one averaged row per throttle step, detected from the rows' shape; "
    "every row is taken as a steady-state point",
}


@dataclass(frozen=True)
class Dataset:
    """Samples of one stand log, in time order. Thrust is per rotor on the load cell, N,
    pulling positive; throttle is in the file's native scale."""

    path: str
    format: str
    throttle_scale: ThrottleScale
    throttle_native: FloatArray
    thrust_n: FloatArray
    voltage_v: FloatArray
    line: IntArray  # 1-based line number of each sample in the source file
    time_s: FloatArray | None = None
    current_a: FloatArray | None = None
    rpm: FloatArray | None = None
    rotors_on_esc: int | None = None
    # What the recorder knew (thrustmap Ds logs): the plan step of each sample (-1: outside the
    # plan, e.g. the spin-down after the stop) and whether the runner had seen it settled.
    step: IntArray | None = None
    settled: BoolArray | None = None
    sha256: str = ""
    meta: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.thrust_n)

    @property
    def throttle_pct(self) -> FloatArray:
        return self.throttle_scale.to_pct(self.throttle_native)

    @property
    def name(self) -> str:
        return self.path.replace("\\", "/").rsplit("/", 1)[-1]

    def subset(self, mask: npt.NDArray[np.bool_]) -> Dataset:
        def pick(a: FloatArray | None) -> FloatArray | None:
            return None if a is None else a[mask]

        return replace(
            self,
            throttle_native=self.throttle_native[mask],
            thrust_n=self.thrust_n[mask],
            voltage_v=self.voltage_v[mask],
            line=self.line[mask],
            time_s=pick(self.time_s),
            current_a=pick(self.current_a),
            rpm=pick(self.rpm),
            step=None if self.step is None else self.step[mask],
            settled=None if self.settled is None else self.settled[mask],
        )

    def source_record(self) -> dict[str, Any]:
        return {"path": self.path, "sha256": self.sha256, "format": self.format, "rows": len(self)}
