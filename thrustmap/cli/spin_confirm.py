"""The ways out of a command that can spin a motor, decided in one place.

Every command that spins (``spin``, ``sweep``) asks through :func:`confirm_spin`, and every way
out of that question is one outcome: a yes goes on; a no, or no answer at all (no terminal to
ask, stdin closed: ``< /dev/null``, a cron job), is a refusal before anything was opened —
exit 2, "nothing spun", and how to confirm (``--yes``); Ctrl-C at the question is an
interruption (exit 130 through :func:`thrustmap.cli.main`), also before anything spun. The
exit codes themselves live in ``thrustmap.cli.main`` (a ``ThrustmapError`` is 2, Ctrl-C 130,
a bug 1) and ``rig.session.exit_code`` (a run's outcome and its stop verification).
"""

from __future__ import annotations

import sys

import click

YES = frozenset({"y", "yes"})


class Refused(click.ClickException):
    """Nothing spun: the safety question was answered no, or could not be asked. Exit 2, as a
    ``ThrustmapError`` in :func:`thrustmap.cli.main`, and also when the command is invoked
    through click directly (tests, embedding)."""

    exit_code = 2


def confirm_spin(question: str, *, yes: bool) -> None:
    """Ask ``question`` on stderr and read the answer from stdin, unless ``yes`` (``--yes``).

    Returns on yes; raises :class:`Refused` (exit 2) on anything else, naming why nothing
    spun."""
    if yes:
        return
    click.echo(f"{question} [y/N]: ", err=True, nl=False)
    try:
        line, typed = sys.stdin.readline(), sys.stdin.isatty()
    except (AttributeError, OSError, ValueError):  # no stdin, or closed
        line, typed = "", False
    except KeyboardInterrupt:  # Ctrl-C at the question: exit 130, and say what did not happen
        raise KeyboardInterrupt("at the safety question: nothing spun") from None
    if not line or not typed:
        click.echo("", err=True)  # the answer was not typed: end the question's line
    if not line:  # EOF: nobody to ask
        raise Refused(
            "no answer to the safety question (no terminal to ask: stdin is closed or empty): "
            "nothing spun; --yes confirms that the propellers are on and the area is clear"
        )
    if line.strip().lower() not in YES:
        raise Refused("refused: nothing spun (answer y, or give --yes, to spin)")
