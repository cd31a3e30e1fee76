"""Simulated stand logs in third-party formats (fixtures for the loaders and selection).

``crazyflie_sysid_sim.csv``: the Crazyflie system-id deck's staircase (``rig.sim.sysid``):
10 ms rows, one command every 100 ms up to full and back down, a load cell converting at 10 SPS
on its own (slightly slow) clock and holding between conversions, rotor lag, a 1S battery
sagging from 3.9 V to about 3.1 V.

Regenerate: ``cd tests && python -m support.regenerate``.
"""

from __future__ import annotations

from pathlib import Path

from thrustmap.rig.sim.sysid import StaircaseSpec, simulate_staircase, write_csv

#: the fixture's simulation: a 10 SPS converter on its own oscillator runs a few % slow, so a
#: 100 ms stair sometimes holds no fresh reading at all
CRAZYFLIE_SYSID = {"seed": 1, "cell_update_s": 0.104}


def write_fixtures(folder: Path) -> list[Path]:
    return [
        write_csv(
            simulate_staircase(StaircaseSpec(**CRAZYFLIE_SYSID)), folder / "crazyflie_sysid_sim.csv"
        )
    ]
