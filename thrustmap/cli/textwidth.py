"""Text that fits the terminal: help, wrapped lines, and tables that turn vertical.

Every human-readable line the CLI prints goes through here, so on a terminal it wraps at the
terminal's width (never narrower than :data:`MIN_WIDTH`) between words, never inside one: a
word longer than the line (a path, a URL) stays whole on a line of its own. Hyphens are not
break points (``stairs-up``, ``sim://tyto-1585`` stay whole). A table that does not fit is
printed as one block of ``name: value`` lines per row.

Output that is not a terminal (a pipe, a file) keeps whole lines, so ``grep`` finds them.
Machine-readable output (``--json``, CSV, an export written to stdout) never passes through here.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable, Sequence

import click
from click._textwrap import TextWrapper

#: the narrowest width text is wrapped at (a narrower terminal still gets 80 columns)
MIN_WIDTH = 80


def width(*, err: bool = False) -> int | None:
    """Columns to wrap stdout (stderr with ``err``) at: the terminal's width, at least
    :data:`MIN_WIDTH`; None (do not wrap) when that stream is not a terminal.

    ``$COLUMNS`` is not read: a pipe keeps whole lines even where it is set (GNU readline, which
    Python's debugger and REPL load, exports it into every child process).
    """
    stream = sys.stderr if err else sys.stdout  # the stream click writes to (a test swaps it)
    try:
        if stream is not None and stream.isatty():
            return max(MIN_WIDTH, os.get_terminal_size(stream.fileno()).columns)
    except (OSError, ValueError, AttributeError):
        pass
    return None


def _wrapper(cols: int, initial_indent: str = "", subsequent_indent: str = "") -> TextWrapper:
    return TextWrapper(
        max(cols, 10),
        initial_indent=initial_indent,
        subsequent_indent=subsequent_indent,
        replace_whitespace=False,
        break_long_words=False,
        break_on_hyphens=False,
    )


def wrap(text: str, cols: int | None = None, *, err: bool = False, hang: int = 2) -> str:
    """Each line of ``text`` wrapped at ``cols`` (default: the width of stdout, or of stderr
    with ``err``, see :func:`width`) between words.

    A continuation line keeps the line's own indentation plus ``hang`` spaces, so a wrapped
    item still reads as one. Lines that fit are left exactly as they are.
    """
    cols = width(err=err) if cols is None else cols
    if cols is None:
        return text
    out: list[str] = []
    for line in text.expandtabs().split("\n"):
        if len(line) <= cols:
            out.append(line)
            continue
        body = line.lstrip(" ")
        indent = " " * (len(line) - len(body))
        out.append(_wrapper(cols, indent, indent + " " * hang).fill(body))
    return "\n".join(out)


def plural(n: int, word: str, many: str | None = None) -> str:
    """``n`` and ``word`` agreeing in number: "1 log", "2 logs", "1 sample" ("many" if not +s)."""
    return f"{n} {word if n == 1 else (many or word + 's')}"


def echo(text: str = "", *, err: bool = False, nl: bool = True) -> None:
    """``click.echo`` for human-readable text: wrapped at the terminal's width."""
    click.echo(wrap(text, err=err), err=err, nl=nl)


def table(
    headers: Sequence[str],
    rows: Sequence[Sequence[str]],
    *,
    right: Sequence[bool] | None = None,
    cols: int | None = None,
    sep: str = "  ",
) -> str:
    """Rows under their headers, or, when that is wider than the terminal (or ``cols``), one
    block per row.

    ``right`` marks the columns aligned right (numbers). The vertical layout repeats the
    header before each value (``mean %: 0.388``), one value a line, a blank line between rows,
    each value wrapped to the width.
    """
    cols = width() if cols is None else cols
    n = len(headers)
    align = list(right) if right is not None else [False] * n
    cells = [[str(c) for c in row] for row in rows]
    widths = [max([len(headers[i]), *(len(r[i]) for r in cells)]) for i in range(n)]
    total = sum(widths) + len(sep) * (n - 1)
    if cols is None or total <= cols:

        def line(values: Sequence[str]) -> str:
            parts = [
                f"{v:>{widths[i]}}" if align[i] else f"{v:<{widths[i]}}"
                for i, v in enumerate(values)
            ]
            return sep.join(parts).rstrip()

        lines = [line(headers), "-" * total]
        lines += [line(r) for r in cells]
        return "\n".join(lines)
    key_w = max(len(h) for h in headers) + 1
    blocks = []
    for r in cells:
        block = [
            _wrapper(cols, f"{h + ':':<{key_w}} ", " " * (key_w + 1)).fill(v) if v else h + ":"
            for h, v in zip(headers, r, strict=True)
        ]
        blocks.append("\n".join(block))
    return "\n\n".join(blocks)


# --- help -------------------------------------------------------------------------------------


def _wrap_text(
    text: str,
    cols: int,
    initial_indent: str = "",
    subsequent_indent: str = "",
    preserve_paragraphs: bool = False,
) -> str:
    """click's ``wrap_text`` without breaks inside words or at hyphens."""
    wrapper = _wrapper(cols, initial_indent, subsequent_indent)
    text = text.expandtabs()
    if not preserve_paragraphs:
        return wrapper.fill(text)
    paragraphs: list[tuple[int, bool, str]] = []
    buf: list[str] = []
    indent: int | None = None

    def flush() -> None:
        if buf:
            raw = buf[0].strip() == "\b"
            body = "\n".join(buf[1:]) if raw else " ".join(buf)
            paragraphs.append((indent or 0, raw, body))
            buf.clear()

    for line in text.splitlines():
        if not line:
            flush()
            indent = None
            continue
        if indent is None:
            stripped = line.lstrip()
            indent = len(line) - len(stripped)
            line = stripped
        buf.append(line)
    flush()
    out = []
    for par_indent, raw, body in paragraphs:
        with wrapper.extra_indent(" " * par_indent):
            out.append(wrapper.indent_only(body) if raw else wrapper.fill(body))
    return "\n\n".join(out)


class HelpFormatter(click.HelpFormatter):
    """click's help layout, wrapped between words only.

    A usage line never breaks inside ``{steps|stairs-up|...}``: the choices wrap at their
    ``|`` separators, and a hyphenated word is never split.
    """

    def __init__(
        self, indent_increment: int = 2, width: int | None = None, max_width: int | None = None
    ) -> None:
        super().__init__(indent_increment, width, max_width)

    def write_usage(self, prog: str, args: str = "", prefix: str | None = None) -> None:
        if prefix is None:
            prefix = "Usage: "
        usage_prefix = f"{prefix:>{self.current_indent}}{prog} "
        text_width = self.width - self.current_indent
        if not args:
            self.write(usage_prefix.rstrip(" ") + "\n")
            return
        # a choice list {a|b|c} may wrap after a '|': a marked space there, removed after
        args = args.replace("|", "|\x00 ")
        if text_width >= len(usage_prefix) + 20:
            indent = " " * len(usage_prefix)
            text = _wrap_text(args, text_width, usage_prefix, indent)
        else:
            self.write(usage_prefix.rstrip(" ") + "\n")
            indent = " " * (max(self.current_indent, len(prefix)) + 4)
            text = _wrap_text(args, text_width, indent, indent)
        self.write(text.replace("\x00 ", "").replace("\x00", "") + "\n")

    def write_text(self, text: str) -> None:
        indent = " " * self.current_indent
        self.write(_wrap_text(text, self.width, indent, indent, preserve_paragraphs=True))
        self.write("\n")

    def write_dl(
        self, rows: Iterable[tuple[str, str]], col_max: int = 30, col_spacing: int = 2
    ) -> None:
        rows = list(rows)
        first_w = max((len(first) for first, _ in rows), default=0)
        first_col = min(first_w, col_max) + col_spacing
        for first, second in rows:
            self.write(f"{'':>{self.current_indent}}{first}")
            if not second:
                self.write("\n")
                continue
            if len(first) <= first_col - col_spacing:
                self.write(" " * (first_col - len(first)))
            else:
                self.write("\n" + " " * (first_col + self.current_indent))
            text_width = max(self.width - first_col - self.current_indent, 10)
            lines = _wrap_text(second, text_width, preserve_paragraphs=True).splitlines()
            if not lines:
                self.write("\n")
                continue
            self.write(lines[0] + "\n")
            for line in lines[1:]:
                self.write(f"{'':>{first_col + self.current_indent}}{line}\n")


class Context(click.Context):
    """A click context whose help uses :class:`HelpFormatter`."""

    formatter_class = HelpFormatter


def use_formatter(command: click.Command) -> click.Command:
    """Give ``command`` (and, for a group, its subcommands) the word-wrapping help formatter."""
    command.context_class = Context
    if isinstance(command, click.Group):
        for sub in command.commands.values():
            use_formatter(sub)
    return command


def short_usage(ctx: click.Context) -> str:
    """A group's usage, its subcommands in one line each, and where the full help is."""
    formatter = ctx.make_formatter()
    formatter.write_usage(ctx.command_path, " ".join(ctx.command.collect_usage_pieces(ctx)))
    command = ctx.command
    if isinstance(command, click.Group):
        rows = []
        for name in command.list_commands(ctx):
            sub = command.get_command(ctx, name)
            if sub is not None and not sub.hidden:
                rows.append((name, sub.get_short_help_str(formatter.width)))
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)
    formatter.write_paragraph()
    formatter.write_text(f"Try '{ctx.command_path} --help' for help; a command is needed.")
    return formatter.getvalue().rstrip("\n")
