"""Registers every built-in simulated peer for ``sim://`` with the physics plant behind it.

Peers of one process share a simulated *bench* (one motor/ESC/battery plant) by name, so a
simulated flight controller and a simulated stand act on the same rotor:

    sim://betaflight?plant=xnova-2207-6s&rotors=4     (the FC that drives the ESC)
    sim://tyto-1585?drive_esc=0                        (the stand on the same bench)

Plant options (on any peer of the bench; the first peer that names them builds the plant):
``bench`` (name, default ``default``), ``plant`` (preset: ``xnova-2207-6s``, ``crazyflie-2.1``),
``rotors`` (rotors on the ESC, 1 = SR, 4 = MR), ``seed`` (noise), ``noise`` (0 turns it off).
"""

from __future__ import annotations

from collections.abc import Mapping

from thrustmap.core.errors import ConfigError
from thrustmap.rig.sim.mavlink_peers import register_mavlink_peers
from thrustmap.rig.sim.msp_peer import register_msp_peers
from thrustmap.rig.sim.options import MAX_SIM_MOTORS, opt_flag, opt_int
from thrustmap.rig.sim.physics import PhysicsPlant, make_plant
from thrustmap.rig.sim.stand_peers import register_stand_peers

PLANT_OPTIONS = ("bench", "plant", "rotors", "seed", "noise")
DEFAULTS = {"plant": "xnova-2207-6s", "rotors": "1", "seed": "1", "noise": "1"}
#: rotors a simulated bench can have on its ESC
ROTOR_COUNTS = ("1", "2", "3", "4", "6", "8")

_benches: dict[str, tuple[dict[str, str], PhysicsPlant]] = {}


def bench_plant(options: Mapping[str, str]) -> PhysicsPlant:
    """The plant of the bench ``options['bench']``, built on first use."""
    name = options.get("bench", "default")
    given = {k: options[k] for k in DEFAULTS if k in options}
    if name in _benches:
        spec, plant = _benches[name]
        clash = {k: v for k, v in given.items() if spec[k] != v}
        if clash:
            raise ConfigError(
                f"simulated bench '{name}' already has {', '.join(f'{k}={spec[k]}' for k in clash)}; "
                f"got {', '.join(f'{k}={v}' for k, v in clash.items())}"
            )
        return plant
    spec = {**DEFAULTS, **given}
    rotors = opt_int(spec, "rotors", 1, lo=1, hi=8, what="the rotors on the ESC (1 SR, 4 MR)")
    if str(rotors) not in ROTOR_COUNTS:
        raise ConfigError(
            f"sim option rotors={rotors}: expected the rotors on the ESC, one of "
            f"{', '.join(ROTOR_COUNTS)} (1 for SR, 4 for MR)"
        )
    seed = opt_int(spec, "seed", 1)
    plant = make_plant(spec["plant"], rotors_on_esc=rotors, seed=seed,
                       noise=opt_flag(spec, "noise", True))  # fmt: skip
    _benches[name] = (spec, plant)
    return plant


def reset_benches() -> None:
    """Forget every simulated bench (each new sweep or test starts with a fresh battery)."""
    _benches.clear()


def _mavlink_plant(options: Mapping[str, str]) -> PhysicsPlant:
    # A vehicle declared with N motors has N rotors spinning unless the bench says otherwise.
    if "motors" in options and "rotors" not in options:
        motors = opt_int(options, "motors", 4, lo=1, hi=MAX_SIM_MOTORS)
        if str(motors) not in ROTOR_COUNTS:
            raise ConfigError(
                f"sim option motors={motors}: the simulated bench spins {', '.join(ROTOR_COUNTS)} "
                "rotors; give rotors= for a different count on the ESC"
            )
        options = {**options, "rotors": str(motors)}
    return bench_plant(options)


# The peer modules register nothing themselves: this module is the one place sim:// names are
# bound, so a peer is never silently built on a stand-in plant because of import order.
register_msp_peers(bench_plant, plant_options=PLANT_OPTIONS)
register_stand_peers(bench_plant, plant_options=PLANT_OPTIONS)
register_mavlink_peers(_mavlink_plant)
