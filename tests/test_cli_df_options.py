"""The Df filter options of `flightlog extract`, `fleet extract` and `gamma live` are made from
DfOptions, the one place their defaults, help and units are declared."""

from __future__ import annotations

import dataclasses

import click
import pytest
from click.testing import CliRunner

from thrustmap.cli import df_options as gen
from thrustmap.cli.fleet import extract_cmd as fleet_extract
from thrustmap.cli.flight import extract_cmd as flight_extract
from thrustmap.cli.gammalive import gamma_live_cmd
from thrustmap.fitting.df_options import OPTION_FIELDS, DfOptions, option_flag

COMMANDS = {
    "flightlog extract": (flight_extract, gen.EXTRACT_FIELDS),
    "fleet extract": (fleet_extract, gen.EXTRACT_FIELDS),
    "gamma live": (gamma_live_cmd, gen.LIVE_FIELDS),
}
FLAGS = {option_flag(name) for name in OPTION_FIELDS}


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_each_df_option_is_generated_with_the_dfoptions_default(command: str) -> None:
    cmd, names = COMMANDS[command]
    defaults = {f.name: f.default for f in dataclasses.fields(DfOptions)}
    made = {p.name: p for p in cmd.params if isinstance(p, gen.DfOption)}
    assert tuple(made) == names  # exactly the subset named in thrustmap/cli/df_options.py
    for name, p in made.items():
        assert p.opts == [option_flag(name)]
        if p.required:
            assert name == "mass_kg" and command == "gamma live"
        else:
            assert p.default == defaults[name], name
        assert p.help and OPTION_FIELDS[name].metadata["help"] in p.help
    # no other option of the command takes a DfOptions flag (a hand-written copy with its own
    # literal default would be one)
    others = [o for p in cmd.params if not isinstance(p, gen.DfOption) for o in p.opts]
    assert not FLAGS & set(others)


def test_the_flags_and_defaults_reach_dfoptions() -> None:
    """Every generated option, given on a command line, lands in its DfOptions field."""
    seen: dict[str, object] = {}

    @click.command()
    @gen.df_click_options(gen.EXTRACT_FIELDS)
    def cmd(**df_values: object) -> None:
        seen.update(DfOptions(**df_values).__dict__)  # type: ignore[arg-type]

    args = ["--mass-kg", "1.5", "--rotors", "6", "--thrust-source", "norm", "--rate-hz", "5",
            "--accel-tol", "2", "--tilt-max-deg", "20", "--settle-s", "1", "--min-height-m",
            "0.2", "--climb-max", "3"]  # fmt: skip
    res = CliRunner().invoke(cmd, args)
    assert res.exit_code == 0, res.output
    assert {k: seen[k] for k in gen.EXTRACT_FIELDS} == {
        "mass_kg": 1.5, "rotors": 6, "thrust_source": "norm", "rate_hz": 5.0,
        "accel_tol_mps2": 2.0, "tilt_max_deg": 20.0, "settle_s": 1.0, "min_height_m": 0.2,
        "climb_max_mps": 3.0,
    }  # fmt: skip
    res = CliRunner().invoke(cmd, [])
    assert res.exit_code == 0 and seen == DfOptions().__dict__


def test_a_required_option_is_still_required() -> None:
    res = CliRunner().invoke(gamma_live_cmd, ["replay://x.tlog", "--map", "m.json"])
    assert res.exit_code == 2 and "Missing option '--mass-kg'" in res.output


def test_the_validation_names_the_generated_flag() -> None:
    from thrustmap.core.errors import ConfigError

    with pytest.raises(ConfigError, match=r"^--accel-tol 0: expected 0\.05\.\.9\.80665 m/s²$"):
        DfOptions(accel_tol_mps2=0.0)
    with pytest.raises(ValueError, match="max_gap_s"):
        gen.df_click_options(("max_gap_s",))
