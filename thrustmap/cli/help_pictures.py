"""Where the pictures are: one line at the end of every command's --help.

The group attaches it when it loads a command (``thrustmap.cli.LazyGroup``), so each command's
help says how to see its results without every module repeating it.
"""

from __future__ import annotations

import click

REPORT = "`thrustmap report MAP -o report.html`"
PLOT = "`thrustmap plot FIGURE MAP -o fig.png|svg|pdf`"

#: command path (as typed after `thrustmap`) -> where its pictures are
WHERE: dict[str, str] = {
    "sweep": "Pictures: a live panel while it runs (on a terminal); after `thrustmap fit`, "
    f"{REPORT} shows the sweep and what selection kept.",
    "spin": "Pictures: a live panel while it spins (on a terminal).",
    "demo": "Pictures: the demo writes an HTML report of each map and prints its path.",
    "fit": f"Pictures: {REPORT} (surface, residuals, validation, coverage) or {PLOT}.",
    "compare": f"Pictures: {REPORT} has this table for every model, with the figures.",
    "evaluate": f"Pictures: {REPORT} and {PLOT} (residuals, coverage).",
    "predict": f"Pictures: {PLOT} with FIGURE surface or slices.",
    "inspect": "Pictures: `thrustmap plot sweep MAP` shows the samples and what selection kept.",
    "export": f"Pictures: {REPORT} lists every firmware's parameters with their residual.",
    "gamma": f"Pictures: {REPORT} on the corrected map; {PLOT} with gamma or errors-by-voltage.",
    "gamma fit": f"Pictures: {REPORT} on the corrected map; `thrustmap plot gamma|"
    "errors-by-voltage MAP -o fig.png`.",
    "flightlog": f"Pictures: after `gamma fit`, {REPORT} plots γ(B) and the flight errors.",
    "report": f"Pictures: this report; single figures for papers with {PLOT}.",
    "plot": f"Pictures: these figures, all together in {REPORT}.",
}
#: commands with nothing to picture (hardware identity, the model list): no line
NONE = frozenset({"ports", "probe", "models"})
DEFAULT = f"Pictures: {REPORT} (every figure and table in one file) and {PLOT}."


def attach(command: click.Command, path: str) -> click.Command:
    """Append the pictures line to ``command``'s help epilog (and its subcommands')."""
    if path in NONE:
        return command
    line = WHERE.get(path, DEFAULT)
    if not command.epilog or line not in command.epilog:
        command.epilog = f"{command.epilog}\n\n{line}" if command.epilog else line
    if isinstance(command, click.Group):
        for name, sub in command.commands.items():
            attach(sub, f"{path} {name}")
    return command
