"""Property tests for the stream codecs and the text parsers: any bytes, any chunking.

Decoders of MSP, MAVLink, Tyto and line stands see whatever a serial line delivers: random bytes,
valid frames torn at any point, frames spliced with garbage. They may report protocol errors
(typed, ThrustmapError) but never raise anything else, never hold more than a bounded buffer, and
decode the same frames whatever the chunking. The JSON and transcript parsers take any text and
answer with a value or one typed error.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from thrustmap.core.errors import ThrustmapError

FAST = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])

chunks = st.lists(st.binary(max_size=300), max_size=12)


def _split(data: bytes, cuts: list[int]) -> list[bytes]:
    points = sorted({c % (len(data) + 1) for c in cuts})
    out, last = [], 0
    for p in points:
        out.append(data[last:p])
        last = p
    out.append(data[last:])
    return out


# -- MSP ------------------------------------------------------------------------------------------


@FAST
@given(chunks)
def test_msp_decoder_takes_any_bytes(parts: list[bytes]) -> None:
    from thrustmap.protocols.msp.framing import MspDecoder

    dec = MspDecoder()
    total = 0
    for part in parts:
        total += len(part)
        for event in dec.feed_events(part):
            assert isinstance(event, ThrustmapError) or hasattr(event, "payload")
        assert dec.pending_bytes <= total


@FAST
@given(
    st.lists(st.tuples(st.integers(0, 255), st.binary(max_size=64)), min_size=1, max_size=6),
    st.lists(st.integers(0, 10_000), max_size=8),
    st.binary(max_size=40),
)
def test_msp_frames_survive_any_chunking_and_garbage(
    frames: list[tuple[int, bytes]], cuts: list[int], garbage: bytes
) -> None:
    from thrustmap.protocols.msp.framing import MspDecoder, MspVersion, encode_reply

    stream = b"".join(encode_reply(cmd, payload, MspVersion.V2) for cmd, payload in frames)
    dec = MspDecoder()
    got = []
    for part in _split(garbage.replace(b"$", b"") + stream, cuts):
        got.extend(dec.feed(part))
    assert [(f.cmd, bytes(f.payload)) for f in got] == [(c, p) for c, p in frames]


# -- MAVLink --------------------------------------------------------------------------------------


@FAST
@given(chunks)
def test_mavlink_codec_takes_any_bytes(parts: list[bytes]) -> None:
    from thrustmap.protocols.mavlink.codec import MavlinkCodec

    codec = MavlinkCodec()
    for part in parts:
        for msg in codec.feed(part):
            assert msg.get_type() != "BAD_DATA"


@FAST
@given(st.lists(st.integers(0, 10_000), max_size=8), st.binary(max_size=40))
def test_mavlink_heartbeats_survive_chunking(cuts: list[int], garbage: bytes) -> None:
    from pymavlink.dialects.v20 import common as mavlink2

    from thrustmap.protocols.mavlink.codec import MavlinkCodec

    sender = MavlinkCodec(system_id=1, component_id=1)
    beats = [sender.encode(mavlink2.MAVLink_heartbeat_message(2, 12, 0, k, 3, 3)) for k in range(3)]
    clean = garbage.replace(b"\xfd", b"").replace(b"\xfe", b"")
    receiver = MavlinkCodec()
    got = []
    for part in _split(clean + b"".join(beats), cuts):
        got.extend(receiver.feed(part))
    assert [m.custom_mode for m in got if m.get_type() == "HEARTBEAT"] == [0, 1, 2]


# -- stands ---------------------------------------------------------------------------------------


@FAST
@given(chunks)
def test_tyto_decoder_takes_any_bytes(parts: list[bytes]) -> None:
    from thrustmap.protocols.stands.tyto import TytoDecoder

    dec = TytoDecoder()
    for part in parts:
        for event in dec.feed_events(part):
            assert not isinstance(event, Exception) or isinstance(event, ThrustmapError)


LINE_PRESETS = [
    "thrustmap-line",
    "generic-hold-csv",
    "einsz-whoop",
    "mqtb-teststand",
    "avenhaus-thrust-stand",
    "tiny-thrust-stand",
    "victorhook-thruststand",
]


@FAST
@given(chunks, st.sampled_from(LINE_PRESETS))
def test_line_stand_decoder_takes_any_bytes(parts: list[bytes], name: str) -> None:
    from thrustmap.protocols.stands.line import LineStandDecoder
    from thrustmap.protocols.stands.line_presets import preset

    dec = LineStandDecoder(preset(name))
    for part in parts:
        for event in dec.feed_events(part):
            assert not isinstance(event, Exception) or isinstance(event, ThrustmapError)


# -- JSON and transcripts -------------------------------------------------------------------------

json_values = st.recursive(
    st.none() | st.booleans() | st.floats(allow_nan=False) | st.integers() | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=4), inner),
    max_leaves=20,
)


@FAST
@given(st.text(max_size=300))
def test_loads_json_takes_any_text(text: str) -> None:
    from thrustmap.core.jsonfile import loads_json

    try:
        loads_json(text, source="x.json")
    except ThrustmapError as exc:
        assert "\n" not in str(exc)


def nesting(value: object) -> int:
    """Levels of [ ] and { } a JSON value adds (a scalar adds none)."""
    if isinstance(value, list):
        return 1 + max((nesting(v) for v in value), default=0)
    if isinstance(value, dict):
        return 1 + max((nesting(v) for v in value.values()), default=0)
    return 0


@FAST
@given(json_values, st.integers(1, 400))
def test_loads_json_depth_is_bounded(value: object, depth: int) -> None:
    from thrustmap.core.errors import DataFormatError
    from thrustmap.core.jsonfile import MAX_JSON_DEPTH, loads_json

    text = "[" * depth + json.dumps(value) + "]" * depth
    total = depth + nesting(value)
    try:
        loads_json(text, source="x.json")
        assert total <= MAX_JSON_DEPTH
    except DataFormatError as exc:
        allowed = ("too large", "not a number JSON allows")  # 1e400 / Infinity: strict numbers
        assert total > MAX_JSON_DEPTH or any(a in str(exc) for a in allowed), str(exc)


def test_loads_json_depth_counts_the_value_s_own_levels() -> None:
    """The case hypothesis found: 61 wrapping levels around [[[[]]]] are 65 levels, refused."""
    from thrustmap.core.errors import DataFormatError
    from thrustmap.core.jsonfile import MAX_JSON_DEPTH, loads_json

    assert MAX_JSON_DEPTH == 64
    loads_json("[" * 60 + "[[[[]]]]" + "]" * 60, source="x.json")  # 64 levels: read
    with pytest.raises(DataFormatError, match="deeper than 64"):
        loads_json("[" * 61 + "[[[[]]]]" + "]" * 61, source="x.json")


@settings(max_examples=80, deadline=None)
@given(st.lists(st.text(max_size=120), max_size=6), st.booleans())
def test_transcript_reader_takes_any_lines(lines: list[str], newline: bool) -> None:
    import tempfile

    from thrustmap.protocols.transcript import read_transcript

    header = '{"format": "thrustmap.transcript", "version": 1, "inner": "sim://px4"}'
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "t.jsonl"
        path.write_text("\n".join([header, *lines]) + ("\n" if newline else ""))
        try:
            read_transcript(path, drop_truncated_tail=True)
        except ThrustmapError as exc:
            assert "\n" not in str(exc)
