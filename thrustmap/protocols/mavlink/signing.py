"""MAVLink 2 message signing: the secret key, where it comes from, and a link that uses it.

The key is 32 bytes (the MAVLink signing spec). A user gives it as 64 hex digits or as a file
holding either the 32 raw bytes or the 64 hex digits (``--signing-key FILE|HEX`` or the
environment variable ``THRUSTMAP_MAVLINK_SIGNING_KEY``; a file or the variable keep it off the
process list). ``SigningKey`` never shows the secret: its ``repr``/``str`` say only that it is
hidden, and no error message here repeats what the user typed when it could be a key.

``enable_signing(link, key)`` turns pymavlink's signing on for a ``mavfile``: every outgoing
message is signed; an incoming message is accepted only with a valid signature (pymavlink
checks the key and the replay timestamp), except the radio's own RADIO_STATUS/RADIO (local,
unsigned by design: ArduPilot accepts those unsigned too). A refused message becomes pymavlink's
BAD_DATA, which the session drops; ``SigningStats`` counts them for the diagnosis.
"""

from __future__ import annotations

import hmac
import os
import string
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from thrustmap.core.errors import ConfigError

ENV_VAR = "THRUSTMAP_MAVLINK_SIGNING_KEY"
KEY_BYTES = 32
MAX_KEY_FILE_BYTES = 4096
#: messages a vehicle accepts unsigned and so do we: a telemetry radio's own reports
UNSIGNED_ALLOWED = frozenset({109, 166})  # RADIO_STATUS, RADIO
MAVLINK_IFLAG_SIGNED = 0x01


class SigningKey:
    """A MAVLink 2 signing key that never prints itself."""

    __slots__ = ("_secret", "source")

    def __init__(self, secret: bytes, source: str = "") -> None:
        if len(secret) != KEY_BYTES:
            raise ConfigError(f"a MAVLink signing key is {KEY_BYTES} bytes, got {len(secret)}")
        if not any(secret):
            raise ConfigError(
                "an all-zero MAVLink signing key means 'signing off' to the firmware; "
                "use a real key"
            )
        self._secret = bytes(secret)
        #: where it came from ("--signing-key", the environment variable's name, ...)
        self.source = source

    @property
    def from_environment(self) -> bool:
        """Given by ``THRUSTMAP_MAVLINK_SIGNING_KEY``, not asked for on this command line: a
        device that does not speak MAVLink ignores it instead of refusing it."""
        return self.source == ENV_VAR

    @property
    def secret(self) -> bytes:
        return self._secret

    def __repr__(self) -> str:
        return "SigningKey(<hidden>)"

    __str__ = __repr__

    def __eq__(self, other: object) -> bool:
        return isinstance(other, SigningKey) and hmac.compare_digest(self._secret, other._secret)

    def __hash__(self) -> int:
        return hash(SigningKey)

    def __reduce__(self) -> Any:  # never copied into a pickle (a Dask task, a cache file)
        raise TypeError("a SigningKey is not picklable")


def _hex_key(text: str) -> bytes | None:
    text = text.strip()
    if len(text) == 2 * KEY_BYTES and all(c in string.hexdigits for c in text):
        return bytes.fromhex(text)
    return None


def _looks_like_hex(text: str) -> bool:
    text = text.strip()
    return len(text) >= 16 and all(c in string.hexdigits for c in text)


def parse_signing_key(value: str, *, source: str = "--signing-key") -> SigningKey:
    """A key from 64 hex digits or from a file (32 raw bytes or 64 hex digits).

    ``source`` names where ``value`` came from in errors; a value that could be a mistyped key
    is never repeated."""
    key = _hex_key(value)
    if key is not None:
        return SigningKey(key, source)
    if _looks_like_hex(value):
        raise ConfigError(
            f"{source}: expected 64 hex digits (a 32-byte key) or a key file; got "
            f"{len(value.strip())} hex digits"
        )
    path = Path(value).expanduser()
    try:
        with path.open("rb") as fh:
            data = fh.read(MAX_KEY_FILE_BYTES + 1)
    except OSError as exc:
        raise ConfigError(
            f"{source}: cannot read key file {value!r} ({exc.strerror or exc}); expected 64 hex "
            "digits or a file holding the 32-byte key"
        ) from None
    if len(data) == KEY_BYTES and _hex_key(data.decode("latin-1")) is None:
        return SigningKey(data, source)
    try:
        key = _hex_key(data.decode("ascii")) if len(data) <= MAX_KEY_FILE_BYTES else None
    except UnicodeDecodeError:
        key = None
    if key is None:
        raise ConfigError(
            f"{value}: expected a MAVLink signing key: 32 raw bytes or 64 hex digits "
            f"(the file has {min(len(data), MAX_KEY_FILE_BYTES)}"
            f"{'+' if len(data) > MAX_KEY_FILE_BYTES else ''} bytes)",
        )
    return SigningKey(key, source)


def signing_key_from(value: str | None, environ: Any = None) -> SigningKey | None:
    """The key from an option value, else from ``THRUSTMAP_MAVLINK_SIGNING_KEY``, else None."""
    if value:
        return parse_signing_key(value, source="--signing-key")
    env = os.environ if environ is None else environ
    from_env = env.get(ENV_VAR, "")
    if from_env.strip():
        return parse_signing_key(from_env, source=ENV_VAR)
    return None


def _accept_unsigned(_mav: Any, message_id: int) -> bool:
    return message_id in UNSIGNED_ALLOWED


def sign_mavlink(mav: Any, key: SigningKey, *, link_id: int = 0, timestamp: int = 0) -> None:
    """Turn signing on for a pymavlink ``MAVLink`` object (the sim vehicles' codec uses this;
    a ``mavfile`` goes through :func:`enable_signing`)."""
    mav.signing.secret_key = key.secret
    mav.signing.sign_outgoing = True
    mav.signing.allow_unsigned_callback = _accept_unsigned
    mav.signing.link_id = link_id
    mav.signing.timestamp = timestamp


def enable_signing(link: Any, key: SigningKey, *, link_id: int = 0) -> None:
    """Sign every message ``link`` sends and accept only validly signed ones (see module).

    The timestamp starts at this computer's time (pymavlink's rule, 10 µs units since 2015)."""
    link.setup_signing(
        key.secret,
        sign_outgoing=True,
        allow_unsigned_callback=_accept_unsigned,
        link_id=link_id,
    )


def signing_enabled(link: Any) -> bool:
    mav = getattr(link, "mav", None)
    return mav is not None and getattr(mav.signing, "secret_key", None) is not None


def is_signed(msg: Any) -> bool:
    """The message arrived with a signature block (MAVLink 2 incompat flag 0x01), whether or
    not anyone checked it (pymavlink's ``get_signed()`` is True only for a verified one)."""
    header = getattr(msg, "get_header", None)
    if not callable(header):
        return False
    return bool(int(getattr(header(), "incompat_flags", 0) or 0) & MAVLINK_IFLAG_SIGNED)


@dataclass(frozen=True)
class SigningStats:
    """What the parser saw, for diagnosing a silent vehicle."""

    signed: int  # messages that carried a signature
    good: int  # signatures that matched the key (and a fresh timestamp)
    bad: int  # signatures refused (another key, or a replayed/old timestamp)
    unsigned_refused: int  # unsigned messages refused


def signing_stats(link: Any) -> SigningStats:
    s = link.mav.signing
    bad = int(s.badsig_count)
    return SigningStats(
        int(s.sig_count), int(s.goodsig_count), bad, max(0, int(s.reject_count) - bad)
    )
