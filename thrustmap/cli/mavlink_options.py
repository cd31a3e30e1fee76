"""``--signing-key FILE|HEX``: the one option decorator every MAVLink command shares.

The value (or, without the option, ``THRUSTMAP_MAVLINK_SIGNING_KEY``) becomes a
``thrustmap.protocols.mavlink.signing.SigningKey`` (which never prints itself) before the
command runs; a bad value is one line naming the option or the file, never echoing the key.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, TypeVar

import click

if TYPE_CHECKING:
    from thrustmap.protocols.mavlink.signing import SigningKey

F = TypeVar("F", bound=Callable[..., Any])

SIGNING_ENV_VAR = "THRUSTMAP_MAVLINK_SIGNING_KEY"  # = protocols.mavlink.signing.ENV_VAR


def _parse(ctx: click.Context, param: click.Parameter, value: str | None) -> SigningKey | None:
    from thrustmap.core.errors import ConfigError
    from thrustmap.protocols.mavlink.signing import signing_key_from

    try:
        return signing_key_from(value)
    except ConfigError as exc:
        raise click.BadParameter(exc.message, ctx=ctx, param=param) from None


def signing_key_option(fn: F) -> F:
    """Add ``--signing-key`` (parsed to a ``SigningKey`` or None) as ``signing_key``."""
    return click.option(
        "--signing-key",
        "signing_key",
        default=None,
        metavar="FILE|HEX",
        expose_value=True,
        callback=_parse,
        help="MAVLink 2 signing key: a file (32 bytes or 64 hex digits) or 64 hex digits; "
        f"default ${SIGNING_ENV_VAR}. Messages are signed and unsigned ones refused.",
    )(fn)
