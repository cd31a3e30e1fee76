"""The names a user can choose — models, losses, validation modes, export targets — in one
light module (no numpy or scipy), so the CLI can offer them in ``--help`` without importing the
fitting machinery. The modules that implement each name import it from here, and
``fitting.models`` checks at import that its registry implements exactly ``MODEL_NAMES``."""

from __future__ import annotations

from typing import Literal

from thrustmap.core.units import SCALES

Loss = Literal["l2", "l1"]
LOSSES: tuple[Loss, ...] = ("l2", "l1")

Validation = Literal["in-sample", "by-file", "kfold"]
VALIDATIONS: tuple[Validation, ...] = ("in-sample", "by-file", "kfold")

#: every model ``fitting.models.MODELS`` implements, in its order
MODEL_NAMES: tuple[str, ...] = (
    "la",
    "linear",
    "poly1",
    "poly2",
    "poly3",
    "poly4",
    "poly2-trunc",
    "poly3-trunc",
    "motor",
)
DEFAULT_MODEL = "motor"

ENCODINGS: tuple[str, ...] = tuple(SCALES)
FIRMWARE_TARGETS: tuple[str, ...] = (
    "c-header",
    "aerostack2",
    "px4",
    "ardupilot",
    "betaflight",
)
TARGETS: tuple[str, ...] = ENCODINGS + FIRMWARE_TARGETS
