"""The shared safe-writing and JSON-reading helpers."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import pytest

from thrustmap.core.errors import ConfigError, DataFormatError
from thrustmap.core.files import atomic_write_text, check_output_path, new_recording_path
from thrustmap.core.jsonfile import Fields, load_json, loads_json


def test_atomic_write_does_not_follow_planted_symlink(tmp_path: Path) -> None:
    victim = tmp_path / "victim.txt"
    victim.write_text("keep")
    # a planted symlink at a predictable temporary name must not be followed
    (tmp_path / "out.json.tmp").symlink_to(victim)
    atomic_write_text(tmp_path / "out.json", "{}")
    assert victim.read_text() == "keep"
    assert (tmp_path / "out.json").read_text() == "{}"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out.json.")]


def test_atomic_write_replacing_a_symlink_replaces_the_link_not_its_target(tmp_path: Path) -> None:
    target = tmp_path / "target.txt"
    target.write_text("keep")
    (tmp_path / "out.txt").symlink_to(target)
    atomic_write_text(tmp_path / "out.txt", "new")
    assert target.read_text() == "keep"


def test_atomic_write_missing_folder_is_a_config_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="does not exist|cannot write"):
        atomic_write_text(tmp_path / "nope" / "x.json", "{}")


def test_output_never_overwrites_an_input(tmp_path: Path) -> None:
    inp = tmp_path / "a.csv"
    inp.write_text("x")
    with pytest.raises(ConfigError, match="overwrite an input"):
        check_output_path(tmp_path / "." / "a.csv", inputs=[inp])
    link = tmp_path / "b.csv"
    link.symlink_to(inp)
    with pytest.raises(ConfigError, match="overwrite an input"):
        check_output_path(link, inputs=[inp])
    plan = check_output_path(tmp_path / "new.json", inputs=[inp])
    assert not plan.replaced


def _error_as_nobody(path: Path) -> str:
    """``check_output_path(path)``'s ConfigError text, checked in a forked child that has given
    up root for nobody (65534): a folder's mode does not bind root, who may write anywhere."""
    read_end, write_end = os.pipe()
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        try:
            os.close(read_end)
            os.setgid(65534)
            os.setuid(65534)
            try:
                check_output_path(path)
                said = "no error"
            except ConfigError as exc:
                said = str(exc)
            os.write(write_end, said.encode())
        finally:
            os._exit(0)
    os.close(write_end)
    with os.fdopen(read_end, "rb") as f:
        said = f.read().decode()
    os.waitpid(pid, 0)
    return said


def test_output_folder_checks(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="does not exist"):
        check_output_path(tmp_path / "missing" / "x.json")
    # a folder every user can reach (pytest's own is root's alone), holding a read-only one
    base = Path(tempfile.mkdtemp())
    ro = base / "ro"
    ro.mkdir()
    try:
        base.chmod(0o755)
        ro.chmod(0o555)
        if os.access(ro, os.W_OK):  # root: ask as an unprivileged user
            assert "not writable" in _error_as_nobody(ro / "x.json")
        else:
            with pytest.raises(ConfigError, match="not writable"):
                check_output_path(ro / "x.json")
    finally:
        ro.chmod(0o700)
        shutil.rmtree(base)


def test_new_recording_path_never_overwrites(tmp_path: Path) -> None:
    run = tmp_path / "run.csv"
    assert new_recording_path(run, siblings=(".meta.json",)) == run
    (tmp_path / "run.meta.json").write_text("{}")
    assert new_recording_path(run, siblings=(".meta.json",)).name == "run-2.csv"


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("[" * 5000 + "]" * 5000, "nested deeper"),
        ('{"a": NaN}', "not a number JSON allows"),
        ('{"a": Infinity}', "not a number JSON allows"),
        ('{"a": 1e400}', "too large"),
        ('{"a": ' + "9" * 400 + "}", "too large"),
        ('{"a": 1,\n "b": }', "not valid JSON"),
    ],
)
def test_loads_json_rejects_hostile_text(text: str, match: str) -> None:
    with pytest.raises(DataFormatError, match=match) as info:
        loads_json(text, source="m.json")
    assert str(info.value).startswith("m.json")


def test_load_json_reports_bad_utf8_and_line(tmp_path: Path) -> None:
    bad = tmp_path / "cal.json"
    bad.write_bytes(b'{"a": "\xff"}')
    with pytest.raises(DataFormatError, match="not UTF-8"):
        load_json(bad)
    broken = tmp_path / "b.json"
    broken.write_text('{\n"a": 1,\n"b": ]\n}')
    with pytest.raises(DataFormatError) as info:
        load_json(broken)
    assert f"{broken}:3:" in str(info.value)


def test_fields_name_the_path() -> None:
    f = Fields({"cal": {"scale": "x", "n": True}}, source="c.json")
    with pytest.raises(DataFormatError, match=r"field 'cal.scale': expected a number"):
        f.sub("cal").number("scale")
    with pytest.raises(DataFormatError, match=r"field 'cal.n': expected an integer"):
        f.sub("cal").integer("n")
    with pytest.raises(DataFormatError, match=r"field 'cal.zero': missing"):
        f.sub("cal").number("zero")
    with pytest.raises(DataFormatError, match=r"expected one of a, b"):
        Fields({"k": "c"}, source="c.json").string("k", choices=("a", "b"))
    assert Fields({"v": 2}, source="c.json").number("v", minimum=0) == 2.0


def test_atomic_write_gives_an_ordinary_file_mode(tmp_path: Path) -> None:
    """mkstemp files are private (0600): a written map or report must not stay so."""
    umask = os.umask(0o022)
    try:
        atomic_write_text(tmp_path / "map.json", "{}")
        assert (tmp_path / "map.json").stat().st_mode & 0o777 == 0o644
        os.chmod(tmp_path / "map.json", 0o640)
        atomic_write_text(tmp_path / "map.json", "{ }")  # a replaced file keeps its mode
        assert (tmp_path / "map.json").stat().st_mode & 0o777 == 0o640
    finally:
        os.umask(umask)
