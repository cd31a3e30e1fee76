"""The old-ArduCopter rules on the 39 public erlerobot flights, by manifest name (issue 42).

docs/old-arducopter.md and docs/performance.md publish these counts (31 of 39 flights with
>= 100 clean Df samples; `python benchmarks/bench_ardu_fleet.py --manifest` prints them). The
files are pinned by sha256 in benchmarks/public-data.toml and read from THRUSTMAP_PUBLIC_DATA;
every flight is a development flight (the manifest says why none is set aside).
"""

from __future__ import annotations

from pathlib import Path

import pytest
from support.public_data import PublicDataError, PublicFiles, manifest

from thrustmap.core.errors import DataFormatError
from thrustmap.fitting.df.extraction import extract
from thrustmap.fitting.df_options import DfOptions
from thrustmap.flightlogs.detect import read_log

#: the rules named in a flight's report (docs/old-arducopter.md); log-pause is a filter step
RULES = ("inav-baro", "climb-crt", "accelerometer calibrated", "events untimed")
ACC = "accelerometer calibrated"
PAUSE = "log-pause"
UNTIMED = "events untimed"
#: clean Df samples and the rules that fired, per flight (None: refused)
EXPECTED: dict[str, tuple[int | None, set[str]]] = {
    "erle/09-10-2014_25": (1388, {ACC}),
    "erle/09-10-2014_30": (781, {UNTIMED, PAUSE}),
    "erle/09-10-2014_31": (2403, {ACC, UNTIMED, PAUSE}),
    "erle/10-11-2014_103": (1073, set()),
    "erle/10-11-2014_104": (823, set()),
    "erle/10-11-2014_105": (686, set()),
    "erle/11-2-2015_112": (1175, {UNTIMED, PAUSE}),
    "erle/14-11-2014_118": (1567, {ACC, UNTIMED, PAUSE}),
    "erle/15-10-2014_42": (105, {"climb-crt"}),
    "erle/15-10-2014_44": (153, {ACC, "climb-crt"}),
    "erle/15-12-2014_16": (1249, {ACC}),
    "erle/18-03-2014_althold_error": (32, {ACC, "climb-crt"}),
    "erle/18-03-2014_althold_error2": (2, {ACC, "climb-crt", UNTIMED, PAUSE}),
    "erle/19-10-2014_ALT_HOLD_test1": (2070, set()),
    "erle/20-10-2014_land_mode_test1": (736, {ACC, "climb-crt"}),
    "erle/22-12-2014_41": (600, {ACC, "climb-crt", UNTIMED, "inav-baro", PAUSE}),
    "erle/23-9-2014_52": (0, {"climb-crt", UNTIMED, "inav-baro", PAUSE}),
    "erle/25-9-2014_3": (337, {ACC, UNTIMED, PAUSE}),
    "erle/26-11-2014_181": (456, {"climb-crt", "inav-baro"}),
    "erle/29-09-2014_1": (125, {ACC, "climb-crt"}),
    "erle/29-09-2014_2": (76, {ACC, "climb-crt"}),
    "erle/29-09-2014_4": (19, {ACC, "climb-crt", UNTIMED, PAUSE}),
    "erle/30-3-2015_73": (293, {"climb-crt", UNTIMED, "inav-baro", PAUSE}),
    "erle/31-3-2015_83": (37, {ACC, "climb-crt", UNTIMED, "inav-baro", PAUSE}),
    "erle/5-12-2014_218": (2882, {ACC}),
    "erle/6-11-2014_GPS_issues1": (588, set()),
    "erle/6-11-2014_GPS_issues2": (701, {UNTIMED, PAUSE}),
    "erle/6-11-2014_GPS_issues3": (663, {ACC, UNTIMED, PAUSE}),
    "erle/6-11-2014_Loiter_RTL": (1892, {UNTIMED, PAUSE}),
    "erle/6-3-2014_7": (130, {"climb-crt", UNTIMED, PAUSE}),
    "erle/7-9-2014_21": (198, {ACC, UNTIMED, PAUSE}),
    "erle/7-9-2014_24": (49, {ACC, "climb-crt"}),
    "erle/7-9-2014_25": (259, {ACC, "climb-crt", UNTIMED, PAUSE}),
    "erle/8-10-2014_11": (None, set()),
    "erle/8-10-2014_18": (139, {ACC, "climb-crt"}),
    "erle/aux_baroexterno_bmp085": (613, {ACC, UNTIMED, PAUSE}),
    "erle/aux_barointerno": (538, {ACC, "climb-crt", UNTIMED, PAUSE}),
    "erle/copter_Erle-Brain3": (2115, set()),
    "erle/copter_PXFv2.0b+Rpi": (995, {PAUSE}),
}


def _score(public_data: PublicFiles, name: str) -> tuple[int | None, set[str]]:
    try:
        df = extract(read_log(public_data(name)), DfOptions(mass_kg=1.5))
    except DataFormatError as exc:
        assert "mean upward specific force 6.1" in str(exc), exc  # ±20 m/s² of vibration
        return None, set()
    report = df.reports[0]
    fired = {r for r in RULES if any(w.startswith(r) for w in report.warnings)}
    if any(s.name == PAUSE and s.dropped_s > 0 for s in report.steps):
        fired.add(PAUSE)
    return len(df), fired


def test_the_manifest_pins_the_39_flights_of_the_fleet(public_data: PublicFiles) -> None:
    assert sorted(public_data.names(source="erlerobot")) == sorted(EXPECTED)
    assert public_data.names(source="erlerobot", role="set-aside") == []


def test_every_flight_gives_its_published_count_and_rules(public_data: PublicFiles) -> None:
    got = {name: _score(public_data, name) for name in EXPECTED}
    assert got == EXPECTED
    used = [n for n, (samples, _) in got.items() if (samples or 0) >= 100]
    assert len(used) == 31  # "31 of 39" (docs/old-arducopter.md, docs/performance.md)
    # the three shared logs are among them
    assert [got[n][0] for n in ("erle/19-10-2014_ALT_HOLD_test1", "erle/copter_PXFv2.0b+Rpi",
                                "erle/copter_Erle-Brain3")] == [2070, 995, 2115]  # fmt: skip


def test_a_file_whose_bytes_differ_from_the_manifest_fails_naming_the_entry(
    public_data: PublicFiles, tmp_path: Path
) -> None:
    entry = manifest()["erle/7-9-2014_24"]
    fake = tmp_path / entry.local
    fake.parent.mkdir(parents=True)
    data = bytearray(public_data(entry.name).read_bytes())
    data[100] ^= 1
    fake.write_bytes(bytes(data))
    with pytest.raises(PublicDataError, match=r"erle/7-9-2014_24: .* has sha256 .* pins"):
        PublicFiles(tmp_path)(entry.name)
    fake.write_bytes(bytes(data[:-1]))
    with pytest.raises(PublicDataError, match=r"erle/7-9-2014_24: .* is \d+ bytes"):
        PublicFiles(tmp_path)(entry.name)


def test_a_public_data_variable_naming_no_folder_fails_instead_of_skipping(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from support.public_data import public_data_dir

    monkeypatch.setenv("THRUSTMAP_PUBLIC_DATA", str(tmp_path / "nowhere"))
    with pytest.raises(PublicDataError, match="nowhere: not a folder"):
        public_data_dir()
    monkeypatch.setenv("THRUSTMAP_PUBLIC_DATA", str(tmp_path))
    assert public_data_dir() == tmp_path
    with pytest.raises(
        PublicDataError, match=r"erle/7-9-2014_24: .* is missing \(from erlerobot/logs"
    ):
        PublicFiles(tmp_path)("erle/7-9-2014_24")
