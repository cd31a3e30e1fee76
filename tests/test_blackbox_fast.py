"""The bulk (numpy) blackbox decoder against the per-frame reference decoder, frame by frame:
on every shared Betaflight log, on the fixtures, on random logs that use every encoding width,
and on damaged logs (which must reach the reference decoder and decode as it does)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from support import blackbox_encode as be

import thrustmap.flightlogs.blackbox_format as blackbox_format
from thrustmap.flightlogs import blackbox_decode as bd
from thrustmap.flightlogs import blackbox_fast as bf
from thrustmap.flightlogs.blackbox import used_field

FIXTURES = Path(__file__).resolve().parent.parent / "fixtures" / "flightlogs"


def assert_same(fast: blackbox_format.DecodedLog, ref: blackbox_format.DecodedLog) -> None:
    """Every field of the two results equal; the main frames compared one by one."""
    assert fast.main_fields == ref.main_fields
    assert fast.main.shape == ref.main.shape and fast.main.dtype == ref.main.dtype
    differ = np.flatnonzero((fast.main != ref.main).any(axis=1))
    assert not len(differ), (
        f"main frame {differ[0]} differs: {fast.main[differ[0]].tolist()} "
        f"!= {ref.main[differ[0]].tolist()}"
    )
    for f in dataclasses.fields(ref):
        a, b = getattr(fast, f.name), getattr(ref, f.name)
        if isinstance(b, np.ndarray):
            assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b), f.name
        else:
            assert a == b, f.name


def logs_in(path: Path) -> list[bytes]:
    data = path.read_bytes()
    return [data[a:b] for a, b in blackbox_format.split_logs(data)]


def compare_fast(section: bytes) -> None:
    """The fast path covers ``section`` and gives exactly the reference's result, for the full
    decode and for the fields a flight log uses."""
    for keep in (None, used_field):
        fast = bf.decode_log_fast(section, 3, 100, keep_field=keep)
        assert fast is not None, "the fast path does not cover this clean log"
        assert_same(fast, bd.decode_log_reference(section, 3, 100, keep_field=keep))


def test_shared_betaflight_logs_frame_by_frame(shared_data: Path) -> None:
    paths = [
        p
        for p in sorted((shared_data / "flightlogs" / "betaflight").iterdir())
        if p.suffix.lower() in (".bbl", ".bfl")
    ]
    assert paths
    for path in paths:
        sections = logs_in(path)
        assert sections, path
        for section in sections:
            compare_fast(section)


@pytest.mark.parametrize("name", sorted(p.name for p in FIXTURES.glob("*.bbl")))
def test_fixture_logs_frame_by_frame(name: str) -> None:
    for section in logs_in(FIXTURES / name):
        compare_fast(section)


# --- random logs: every encoding width, signs, events, a logging pause --------------------------

#: noise amplitude per field of the simulated hover (be.SIM_MAIN): the residuals it gives span
#: zero groups, 4/8/16-bit tag8_4s16 fields, every tag2_3s32 width and multi-byte varints
AMPLITUDE = [0, 0, 15000, 15000, 15000, 450, 1500, 1_000_000, 1_000_000, 1_000_000, 1_000_000,
             1_000_000, 1_000_000, 1_000_000, 650, 650, 650, 650]  # fmt: skip


def random_log(seed: int, frames: int) -> bytes:
    rng = np.random.default_rng(seed)
    enc = be.Encoder(be.SIM_HEADERS, be.SIM_MAIN, be.SIM_P_PREDICTOR, be.SIM_P_ENCODING,
                     be.SIM_SLOW)  # fmt: skip
    out = bytearray(enc.header_bytes())
    out += enc.event(blackbox_format.EVENT_SYNC_BEEP, 123456)
    out += enc.s_frame([1, 0, 0, 1])
    resume_at, gap_at = frames // 2, 3 * frames // 4
    pause_us = 0
    for k in range(frames):
        if k in (resume_at, gap_at):  # logging paused for 12 s
            pause_us += 12_000_000
        values = be.sim_frame_values(k, 4096, 5_000_000 + pause_us, 10.0)
        scale = rng.choice([0.0, 1e-4, 1e-2, 1.0], size=len(values))
        noise = (rng.uniform(-1, 1, len(values)) * np.array(AMPLITUDE) * scale).astype(int)
        values = values[:2] + [v + int(x) for v, x in zip(values[2:], noise[2:], strict=True)]
        if k == resume_at:  # announced: a resume event, then an intra frame
            out += enc.event(blackbox_format.EVENT_LOGGING_RESUME, values[0], values[1] - 50)
            out += enc.i_frame(values)
        elif k == gap_at or k % 8 == 0:  # the pause at gap_at unannounced: a gap
            out += enc.i_frame(values)
        else:
            out += enc.p_frame(values)
        if k == frames // 3:
            out += enc.s_frame([int(rng.integers(0, 1 << 20)), 3, 0, 1])
            out += enc.event(blackbox_format.EVENT_FLIGHT_MODE, 5, 1)
    out += enc.event(blackbox_format.EVENT_DISARM, 4)
    out += enc.event(blackbox_format.EVENT_LOG_END)
    return bytes(out)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(2, 300))
def test_random_logs_frame_by_frame(seed: int, frames: int) -> None:
    section = random_log(seed, frames)
    compare_fast(section)
    fast = bf.decode_log_fast(section)
    assert fast is not None
    gaps = [w for w in fast.warnings if "12.0 s gap" in w]  # the unannounced pause only
    assert len(gaps) == (1 if 0 < 3 * frames // 4 != frames // 2 else 0)


# --- what the fast path leaves to the reference decoder ----------------------------------------


@pytest.mark.parametrize("seed", range(8))
def test_damaged_logs_decode_as_the_reference_does(seed: int) -> None:
    """Flipped bytes, a truncated tail or a corrupt frame: decode_log equals the reference
    (through the reference where the fast path declines)."""
    rng = np.random.default_rng(seed)
    section = random_log(seed, 200)
    body = section.index(b"\nE") + 1  # past the headers
    data = bytearray(section)
    for k in rng.integers(body, len(data), 1 + seed % 4):
        data[int(k)] = int(rng.integers(0, 256))
    damaged = bytes(data[: int(rng.integers(body + 100, len(data) + 1))])
    for keep in (None, used_field):
        assert_same(
            bd.decode_log(damaged, keep_field=keep),
            bd.decode_log_reference(damaged, keep_field=keep),
        )


def test_truncated_or_corrupt_logs_go_to_the_reference() -> None:
    section = random_log(7, 120)
    truncated = section[:-40]
    assert bf.decode_log_fast(truncated) is None
    assert any("truncated" in w for w in bd.decode_log(truncated).warnings)
    body = section.index(b"\nE") + 1
    garbage = section[:body] + b"\x01\x02" + section[body:]  # bytes no frame starts with
    assert bf.decode_log_fast(garbage) is None
    assert bd.decode_log(garbage).stats["skipped_bytes"] == 2


def test_a_value_needing_the_32_bit_wrap_is_wrapped_in_bulk() -> None:
    """Unsigned vbat driven past 2**32 by its inter-frame deltas (predicted from the previous
    frame, a sum): the bulk decoder wraps it once at the end, exactly as the reference wraps it
    after every frame."""
    enc = be.Encoder(be.SIM_HEADERS, be.SIM_MAIN, be.SIM_P_PREDICTOR, be.SIM_P_ENCODING)
    out = bytearray(enc.header_bytes())
    for k in range(16):
        values = be.sim_frame_values(k, 4096, 5_000_000, 10.0)
        values[6] = 1640  # vbat (unsigned), stepping past 2**32 in the P frames
        if k % 8:
            values[6] = 1640 + k * (1 << 30)
        out += enc.i_frame(values) if k % 8 == 0 else enc.p_frame(values)
    section = bytes(out)
    compare_fast(section)
    decoded = bd.decode_log(section)
    assert int(decoded.main[:, 6].max()) <= 0xFFFFFFFF
    assert decoded.main[1:8, 6].tolist() == [
        (1640 + k * (1 << 30)) % (1 << 32) for k in range(1, 8)
    ]


def test_betaflight_3_throttle_and_motors_below_their_low_end_are_wrapped_in_bulk() -> None:
    """Betaflight 3.x predicts rcCommand[3] from minthrottle and motor[0] from the motor low end
    in intra frames, and logs a value below either as an unsigned residual (1000 - 1070 ->
    2**32 - 70): only the 32-bit wrap brings it back. The motors are averaged in inter frames,
    so they are wrapped at every step; both as the reference decodes them."""
    main = dataclasses.replace(be.SIM_MAIN, predictor=[*be.SIM_MAIN.predictor])
    main.predictor[5] = blackbox_format.PRED_MINTHROTTLE  # rcCommand[3], unsigned varint
    enc = be.Encoder(be.SIM_HEADERS, main, be.SIM_P_PREDICTOR, be.SIM_P_ENCODING)
    out = bytearray(enc.header_bytes())
    for k in range(64):
        values = be.sim_frame_values(k, 4096, 5_000_000, 10.0)
        values[5] = 1000 + (k % 3)  # below minthrottle 1070
        if k < 40:
            values[14:18] = [0, 0, 0, 0]  # disarmed: below the motor low end 158
        out += enc.i_frame(values) if k % 8 == 0 else enc.p_frame(values)
    section = bytes(out)
    compare_fast(section)
    decoded = bd.decode_log(section)
    assert decoded.main[:, 5].tolist() == [1000 + (k % 3) for k in range(64)]
    assert decoded.main[:40, 14:18].tolist() == [[0, 0, 0, 0]] * 40


def test_an_averaged_value_leaving_32_bits_in_inter_frames_goes_to_the_reference() -> None:
    """motor[1] (averaged from the previous two frames, which does not commute with the wrap)
    driven past 2**32 by inter-frame residuals while no intra frame needed the wrap: the
    reference wraps it after every frame; the bulk decoder must not wrap it once at the end."""
    enc = be.Encoder(be.SIM_HEADERS, be.SIM_MAIN, be.SIM_P_PREDICTOR, be.SIM_P_ENCODING)
    out = bytearray(enc.header_bytes())
    prev = prev2 = 0
    for k in range(16):
        values = be.sim_frame_values(k, 4096, 5_000_000, 10.0)
        if k % 8:  # each inter frame: the average of the previous two plus 2**31 - 1
            values[15] = (prev + prev2) // 2 + (1 << 31) - 1
        out += enc.i_frame(values) if k % 8 == 0 else enc.p_frame(values)
        prev2, prev = (values[15], values[15]) if k % 8 == 0 else (prev, values[15])
    section = bytes(out)
    ref = bd.decode_log_reference(section)
    assert int(ref.main[:, 15].max()) <= 0xFFFFFFFF
    fast = bf.decode_log_fast(section)  # declines today; wrong values never
    if fast is not None:
        assert_same(fast, ref)
    assert_same(bd.decode_log(section), ref)


def test_a_bare_residual_out_of_range_goes_to_the_reference() -> None:
    """A field read bare (no prediction: the reference does not wrap it) beyond 32 bits: the
    fast path declines, the reference decodes it."""
    enc = be.Encoder(be.SIM_HEADERS, be.SIM_MAIN, be.SIM_P_PREDICTOR, be.SIM_P_ENCODING)
    out = bytearray(enc.header_bytes())
    for k in range(16):
        values = be.sim_frame_values(k, 4096, 5_000_000, 10.0)
        out += enc.i_frame(values) if k % 8 == 0 else enc.p_frame(values)
    damaged = bytearray(out)
    # the first intra frame's rcCommand[0] (signed varint, predictor zero) as 2**33: 5 bytes
    first = damaged.index(b"I", len(enc.header_bytes()) - 1)
    at = first + 1 + len(be.uvb(4096)) + len(be.uvb(5_000_000))
    old = be.svb(-3)
    assert damaged[at : at + len(old)] == old
    damaged[at : at + len(old)] = bytes([0x80, 0x80, 0x80, 0x80, 0x20])  # zigzag 2**33: 2**32
    section = bytes(damaged)
    assert bf.decode_log_fast(section) is None
    decoded = bd.decode_log(section)
    assert int(decoded.main[0, 2]) == 1 << 32  # the reference keeps a bare residual unwrapped
    assert_same(decoded, bd.decode_log_reference(section))


# --- what real pilots' logs hold: GPS and GPS-home frames, several logs in one file -------------


def gps_log(seed: int, frames: int, start_iteration: int = 4096, start_time_us: int = 5_000_000):
    """A hover log with GPS (G) frames every 5th main frame, a GPS-home (H) frame before the
    first and a new home half way, slow frames, events and an announced logging pause followed
    by a GPS frame (its time is relative to the resume event's). Returns the log and the GPS
    rows and homes it encodes."""
    rng = np.random.default_rng(seed)
    enc = be.Encoder(be.SIM_HEADERS, be.SIM_MAIN, be.SIM_P_PREDICTOR, be.SIM_P_ENCODING,
                     be.SIM_SLOW, be.SIM_GPS, be.SIM_GPS_HOME)  # fmt: skip
    out = bytearray(enc.header_bytes())
    out += enc.event(blackbox_format.EVENT_SYNC_BEEP, start_time_us - 1000)
    out += enc.s_frame([1, 0, 0, 1])
    gps: list[list[int]] = []
    homes: list[list[int]] = []
    home = [
        int(rng.integers(-900_000_000, 900_000_000)),
        int(rng.integers(-1_800_000_000, 1_800_000_000)),
    ]
    resume_at = frames // 2
    pause_us = 0
    for k in range(frames):
        if k in (0, frames // 3):
            homes.append(list(home))
            out += enc.h_frame(home)
        if k == resume_at:
            pause_us += 3_000_000
        values = be.sim_frame_values(k, start_iteration, start_time_us + pause_us, 10.0)
        if k == resume_at:  # a resume event, a GPS frame, then the intra frame
            out += enc.event(blackbox_format.EVENT_LOGGING_RESUME, values[0], values[1] - 70)
            row = [values[1] - 70 + 9, 11, home[0] + 5, home[1] - 5, 120, 30, 1800]
            gps.append(row)
            out += enc.g_frame(row)
            out += enc.i_frame(values)
        else:
            out += enc.i_frame(values) if k % 8 == 0 else enc.p_frame(values)
        if k % 5 == 2:
            row = [values[1] + int(rng.integers(0, 4000)), int(rng.integers(0, 30)),
                   home[0] + int(rng.integers(-20_000, 20_000)),
                   home[1] + int(rng.integers(-20_000, 20_000)),
                   int(rng.integers(0, 20_000)), int(rng.integers(0, 3000)),
                   int(rng.integers(0, 3600))]  # fmt: skip
            gps.append(row)
            out += enc.g_frame(row)
        if k == frames // 3:
            home = [home[0] + 1000, home[1] - 2000]  # a new home (re-armed)
        if k == frames // 4:
            out += enc.s_frame([int(rng.integers(0, 1 << 20)), 3, 0, 1])
            out += enc.event(blackbox_format.EVENT_FLIGHT_MODE, 5, 1)
    out += enc.event(blackbox_format.EVENT_DISARM, 4)
    out += enc.event(blackbox_format.EVENT_LOG_END)
    return bytes(out), gps, homes


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(12, 300))
def test_gps_logs_frame_by_frame_with_their_values(seed: int, frames: int) -> None:
    """GPS and GPS-home frames are covered by the fast path, equal to the reference, and
    decode to the coordinates written (relative to the home of their time)."""
    section, gps, homes = gps_log(seed, frames)
    compare_fast(section)
    fast = bf.decode_log_fast(section)
    assert fast is not None
    assert fast.gps_fields == be.SIM_GPS.names
    assert fast.gps.tolist() == gps
    assert fast.stats["G"] == len(gps) and fast.stats["H"] == len(homes)


def test_a_file_of_several_gps_logs_is_decoded_in_bulk_log_by_log() -> None:
    """A flash dump: several logs one after another (one holding no main frame at all, as
    logging started and stopped at once), then erased flash. Every log takes the fast path,
    and decode_file gives the reference's result for each."""
    logs = [gps_log(s, n, 4096 * (s + 1), 5_000_000 * (s + 1)) for s, n in ((1, 200), (2, 40))]
    enc = be.Encoder(be.SIM_HEADERS, be.SIM_MAIN, be.SIM_P_PREDICTOR, be.SIM_P_ENCODING,
                     be.SIM_SLOW, be.SIM_GPS, be.SIM_GPS_HOME)  # fmt: skip
    empty = (
        enc.header_bytes()
        + enc.event(blackbox_format.EVENT_SYNC_BEEP, 99)
        + enc.event(blackbox_format.EVENT_LOG_END)
    )
    data = logs[0][0] + empty + logs[1][0] + b"\xff" * 5000
    ranges = blackbox_format.split_logs(data)
    assert len(ranges) == 3
    for i, (a, b) in enumerate(ranges):
        for keep in (None, used_field):
            got = bf.decode_log_bulk(data[a:b], i, a, keep_field=keep)
            assert isinstance(got, blackbox_format.DecodedLog), f"log {i + 1} left to the reference"
            assert_same(got, bd.decode_log_reference(data[a:b], i, a, keep_field=keep))
    decoded = bd.decode_file(data)
    assert [len(d.main) for d in decoded] == [200, 0, 40]
    assert decoded[0].gps.tolist() == logs[0][1] and decoded[2].gps.tolist() == logs[1][1]


# --- a log clean up to some point: bulk up to there, the reference from there -------------------


@pytest.mark.parametrize("cut", [-40, -7, -1])
def test_a_truncated_log_is_decoded_in_bulk_up_to_its_tail(cut: int) -> None:
    section, _, _ = gps_log(5, 300)
    truncated = section[:cut]
    got = bf.decode_log_bulk(truncated)
    assert isinstance(got, blackbox_format.ResumeState)
    assert len(got.main) >= 290  # all but the last frames in bulk
    for keep in (None, used_field):
        assert_same(bd.decode_log(truncated, keep_field=keep),
                    bd.decode_log_reference(truncated, keep_field=keep))  # fmt: skip


def test_a_corrupt_stretch_is_left_to_the_reference_from_there_on() -> None:
    section, gps, _ = gps_log(6, 300)
    body = section.index(b"\nE") + 1
    at = body + (len(section) - body) * 2 // 3
    damaged = section[:at] + b"\x01\x02\x03" + section[at:]  # bytes no frame starts with
    got = bf.decode_log_bulk(damaged)
    assert isinstance(got, blackbox_format.ResumeState) and body < got.pos <= at
    decoded = bd.decode_log(damaged)
    assert_same(decoded, bd.decode_log_reference(damaged))
    assert decoded.stats["skipped_bytes"] >= 3 and decoded.ended_cleanly
    assert len(decoded.main) >= 290


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 4), st.booleans(), st.sampled_from([0, 1, 5000]))
def test_randomly_damaged_gps_logs_decode_as_the_reference_does(
    seed: int, flips: int, truncate: bool, erased: int
) -> None:
    """Flipped bytes, a cut-off tail, erased flash (0xFF) after it: as the reference."""
    rng = np.random.default_rng(seed)
    section, _, _ = gps_log(seed, 160)
    body = section.index(b"\nE") + 1
    data = bytearray(section)
    for k in rng.integers(body, len(data), flips):
        data[int(k)] = int(rng.integers(0, 256))
    end = int(rng.integers(body + 100, len(data) + 1)) if truncate else len(data)
    damaged = bytes(data[:end]) + b"\xff" * erased
    for keep in (None, used_field):
        assert_same(
            bd.decode_log(damaged, keep_field=keep),
            bd.decode_log_reference(damaged, keep_field=keep),
        )


@pytest.mark.parametrize("shape", ["uniform", "ragged"])
def test_inter_frame_runs_of_any_lengths(shape: str) -> None:
    """Inter-frame runs all of one length are predicted on a grid, runs of very different
    lengths (many intra frames, then one long run) row by row: both as the reference."""
    enc = be.Encoder(be.SIM_HEADERS, be.SIM_MAIN, be.SIM_P_PREDICTOR, be.SIM_P_ENCODING)
    out = bytearray(enc.header_bytes())
    for k in range(1500):
        values = be.sim_frame_values(k, 4096, 5_000_000, 10.0)
        intra = k % 8 == 0 if shape == "uniform" else k < 1000 or k == 1200
        out += enc.i_frame(values) if intra else enc.p_frame(values)
    compare_fast(bytes(out))


def test_more_logs_frame_by_frame() -> None:
    """Blackbox logs not in the repository (THRUSTMAP_BLACKBOX_LOGS: a folder of .bbl/.bfl/.txt,
    e.g. public logs gathered for a benchmark): every log of every file decodes exactly as the
    reference decoder decodes it, in bulk where it is clean."""
    import os

    folder = os.environ.get("THRUSTMAP_BLACKBOX_LOGS")
    if not folder or not Path(folder).is_dir():
        pytest.skip("THRUSTMAP_BLACKBOX_LOGS is not set to a folder of blackbox logs")
    paths = sorted(
        p for p in Path(folder).rglob("*") if p.suffix.lower() in (".bbl", ".bfl", ".txt")
    )
    assert paths, folder
    for path in paths:
        data = path.read_bytes()
        for i, (a, b) in enumerate(blackbox_format.split_logs(data)):
            for keep in (None, used_field):
                assert_same(
                    bd.decode_log(data[a:b], i, a, keep_field=keep),
                    bd.decode_log_reference(data[a:b], i, a, keep_field=keep),
                )


@pytest.mark.parametrize("case", ["rollover", "time jump"])
def test_an_implausible_frame_hands_over_to_the_reference_there(case: str) -> None:
    """The 32-bit microsecond clock rolling over (after 71.6 min powered), or an inter frame
    11 s after the one before: the frames before it are decoded in bulk, the reference decoder
    takes over from it (rollover bookkeeping, the frame dropped), with the same result."""
    enc = be.Encoder(be.SIM_HEADERS, be.SIM_MAIN, be.SIM_P_PREDICTOR, be.SIM_P_ENCODING,
                     be.SIM_SLOW, be.SIM_GPS, be.SIM_GPS_HOME)  # fmt: skip
    out = bytearray(enc.header_bytes())
    out += enc.h_frame([473_000_000, 85_000_000])
    start_us = (1 << 32) - 2_000_000 if case == "rollover" else 5_000_000
    jump_us = 0
    for k in range(1000):
        if case == "time jump" and k == 700:
            jump_us = 11_000_000
        values = be.sim_frame_values(k, 4096, start_us + jump_us, 10.0)
        values[1] &= 0xFFFFFFFF  # the firmware's clock is 32-bit
        out += enc.i_frame(values) if k % 8 == 0 else enc.p_frame(values)
        if k % 10 == 3:
            out += enc.g_frame([values[1] + 50, 9, 473_000_100, 85_000_000 - k, 50, 3, 90])
    out += enc.event(blackbox_format.EVENT_LOG_END)
    section = bytes(out)
    got = bf.decode_log_bulk(section)
    assert isinstance(got, blackbox_format.ResumeState)
    assert len(got.main) >= 480  # the frames before the rollover (~500) or the jump (700)
    for keep in (None, used_field):
        assert_same(bd.decode_log(section, keep_field=keep),
                    bd.decode_log_reference(section, keep_field=keep))  # fmt: skip
    decoded = bd.decode_log(section)
    if case == "rollover":  # the reference's time keeps counting past 2**32
        assert int(decoded.main[-1, 1]) > 1 << 32 and len(decoded.main) >= 990
    else:
        assert decoded.stats["invalid_main"] >= 1


def test_bulk_decoding_resumes_after_a_corrupt_stretch(monkeypatch: pytest.MonkeyPatch) -> None:
    """A long log with a corrupt stretch early on: bulk up to it, frame by frame across it,
    bulk again from an intra frame past it (not frame by frame to the end); as the reference."""
    section = be.simulate_hover_log(120.0)  # ~500 kB
    body = section.index(b"\nE") + 1
    at = body + (len(section) - body) // 8
    damaged = section[:at] + b"\x01\x02\x03" + section[at + 40 :]  # a frame lost, garbage
    passes: list[tuple[bool, str]] = []
    bulk = bf.decode_log_bulk

    def spy(*args: object, **kwargs: object) -> object:
        got = bulk(*args, **kwargs)  # type: ignore[arg-type]
        passes.append((kwargs.get("start") is not None, type(got).__name__))
        return got

    monkeypatch.setattr(bf, "decode_log_bulk", spy)
    for keep in (None, used_field):
        passes.clear()
        decoded = bd.decode_log(damaged, keep_field=keep)
        assert passes == [(False, "ResumeState"), (True, "DecodedLog")]
        assert_same(decoded, bd.decode_log_reference(damaged, keep_field=keep))
        assert decoded.stats["corrupt"] + decoded.stats["skipped_bytes"] > 0
        assert any("corrupt frame(s)" in w for w in decoded.warnings)


@settings(max_examples=200, deadline=None)
@given(st.binary(min_size=0, max_size=40), st.integers(2, 12))
def test_a_run_of_varints_frames_as_one_varint_at_a_time(data: bytes, count: int) -> None:
    """The framing expression's run of varints (all one byte at once, else one at a time)
    matches exactly what ``count`` varints read one at a time match, on any bytes."""
    import re

    from thrustmap.flightlogs import blackbox_framing as framing

    run = re.compile(framing._varint_run(count), re.DOTALL)
    one_by_one = re.compile(framing._VB * count, re.DOTALL)
    for start in range(len(data) + 1):
        got, want = run.match(data, start), one_by_one.match(data, start)
        assert (got and got.end()) == (want and want.end())


def test_bytes_after_the_log_end_event_are_not_decoded() -> None:
    """A log whose frames end with the log-end event and then hold stray bytes (junk the frames
    do not tile): decoded in bulk up to the event, as the reference decodes it."""
    section = be.simulate_hover_log(2.0)
    assert section.endswith(b"E\xff" + blackbox_format.END_OF_LOG_TEXT)
    for tail in (b"\x01\x02\x03", b"P\x00", b"\xff" * 7 + b"\x00"):
        compare_fast(section + tail)


@settings(max_examples=200, deadline=None)
@given(st.sets(st.integers(0, 255), min_size=1))
def test_a_byte_class_matches_exactly_its_bytes(values: set[int]) -> None:
    """The framing expression's byte classes hold the bytes themselves (escaped where the class
    syntax needs it): each matches exactly the bytes it was built from, without a warning."""
    import re
    import warnings

    from thrustmap.flightlogs import blackbox_framing as framing

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        cls = re.compile(framing._byte_class(sorted(values)), re.DOTALL)
    assert {v for v in range(256) if cls.fullmatch(bytes([v]))} == values


def test_a_tagged_group_of_unused_fields_with_none_set_is_skipped() -> None:
    """INAV 8 logs rcCommand[0..2] (fields a flight log does not use) as a TAG8_8SVB group; a
    frame where none of them changed has a header byte of 0 and no varint after it. The
    per-frame decoder skipping the unused group read it as "no varints" (it raised on such a
    real INAV log before); both decoders agree, with and without the unused fields."""
    p_encoding = [*be.SIM_P_ENCODING]
    p_encoding[2:6] = [blackbox_format.ENC_TAG8_8SVB] * 3 + [blackbox_format.ENC_SIGNED_VB]
    enc = be.Encoder(be.SIM_HEADERS, be.SIM_MAIN, be.SIM_P_PREDICTOR, p_encoding)
    out = bytearray(enc.header_bytes())
    for k in range(40):
        values = be.sim_frame_values(k, 4096, 5_000_000, 10.0)
        values[2:5] = [0, 0, 0] if k < 20 else [k % 3, 0, -1]
        out += enc.i_frame(values) if k % 8 == 0 else enc.p_frame(values)
    section = bytes(out)
    compare_fast(section)
    for keep in (None, used_field):
        ref = bd.decode_log_reference(section, keep_field=keep)
        assert ref.stats["corrupt"] == 0 and len(ref.main) == 40


def test_a_corrupt_stretch_in_a_log_needing_the_wrap_resumes_in_bulk(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Betaflight 3.x values that need the 32-bit wrap (throttle below minthrottle, disarmed
    motors below their low end) and a corrupt stretch early on: the frames across the stretch
    are decoded by the reference with the wrap, as the bulk passes around them are, so the log
    is not decoded again by the reference from its start (a real 4 MB Betaflight 3.1.7 log went
    from 0.5 s to 2.9 s that way); the result is the reference's."""
    main = dataclasses.replace(be.SIM_MAIN, predictor=[*be.SIM_MAIN.predictor])
    main.predictor[5] = blackbox_format.PRED_MINTHROTTLE  # rcCommand[3], unsigned varint
    enc = be.Encoder(be.SIM_HEADERS, main, be.SIM_P_PREDICTOR, be.SIM_P_ENCODING)
    head = enc.header_bytes()
    out = bytearray(head)
    for k in range(40_000):
        values = be.sim_frame_values(k, 4096, 5_000_000, 10.0)
        values[5] = 1000 + (k % 3)  # below minthrottle 1070
        if k % 10_000 < 300:
            values[14:18] = [0, 0, 0, 0]  # disarmed: below the motor low end 158
        out += enc.i_frame(values) if k % 32 == 0 else enc.p_frame(values)
    section = bytes(out)
    assert len(section) - len(head) > 2 * blackbox_format.MIN_HANDBACK_BYTES
    at = len(head) + (len(section) - len(head)) // 8
    damaged = section[:at] + b"\x01\x02\x03" + section[at + 40 :]
    from_start: list[bool] = []
    frame_by_frame = bd._decode_log

    def spy(*args: object, **kwargs: object) -> object:
        from_start.append(kwargs.get("resume") is None)
        return frame_by_frame(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(bd, "_decode_log", spy)
    decoded = bd.decode_log(damaged)
    assert from_start and not any(from_start), from_start
    monkeypatch.setattr(bd, "_decode_log", frame_by_frame)
    assert_same(decoded, bd.decode_log_reference(damaged))
    assert decoded.main[:300, 14:18].tolist() == [[0, 0, 0, 0]] * 300
