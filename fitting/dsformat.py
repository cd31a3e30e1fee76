"""Moved: the Ds log format lives in :mod:`thrustmap.dslog` (writer and reader).

Kept so that older imports (``from thrustmap.fitting.dsformat import DsWriter``) still work;
new code imports :mod:`thrustmap.dslog`.
"""

from __future__ import annotations

from thrustmap.dslog import (
    DATA_COLUMNS,
    DS_FORMAT,
    DS_VERSION,
    DsWriter,
    read_sidecar,
    sidecar_path,
)

__all__ = ["DATA_COLUMNS", "DS_FORMAT", "DS_VERSION", "DsWriter", "read_sidecar", "sidecar_path"]
