"""Command-line interface: ``pedx-graph <command> ...``.

Each sub-package that offers a command has a ``cli`` module with ``register(subparsers)``; this module
only collects them, so importing the CLI stays cheap and one broken command does not hide the others.

Errors a person can read: every error ends the command with one line on stderr, ``pedx-graph: error:
<message>`` naming the path or the config key, and exit code 1; a usage error (a bad flag or value) prints
one line and exits with 2; an interrupt exits with 130.  ``--debug`` (before or after the command) re-raises
the error with its traceback instead.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import re
import sys

#: Modules providing ``register(subparsers)``, in help order.
COMMAND_MODULES = (
    "pedx_graph.body.cli",       # info
    "pedx_graph.sim.cli",        # simulate
    "pedx_graph.detections.cli",  # import
    "pedx_graph.data.noise_cli",  # noise
    "pedx_graph.priors.cli",     # train-prior
    "pedx_graph.solvers.cli",    # fit
    "pedx_graph.solvers.stream_cli",  # stream
    "pedx_graph.baselines.cli",  # baseline
    "pedx_graph.eval.cli",       # eval
    "pedx_graph.eval.report_cli",  # report, experiments
    "pedx_graph.export.cli",     # export
    "pedx_graph.demo",           # demo
    "pedx_graph.config_reference",  # config
)


_RST_ROLE = re.compile(r":(?:func|class|mod|meth|attr|data|obj|exc):`~?([^`]+)`")


def plain_text(text: str) -> str:
    """Help text without reStructuredText markup (descriptions are often module docstrings): roles such as
    :func:`x` become x, ``literal`` and `title` lose their backquotes."""
    return _RST_ROLE.sub(r"\1", text).replace("``", "").replace("`", "")


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Help as plain text (no markup) with every option's default, unless its help already states one, it is
    required, or it is an on/off flag (off by default)."""

    def _format_text(self, text: str) -> str:
        return super()._format_text(plain_text(text))

    def _get_help_string(self, action: argparse.Action) -> str:
        text = plain_text(action.help or "")
        flag = isinstance(action, (argparse._StoreTrueAction, argparse._StoreFalseAction,
                                   argparse._VersionAction, argparse._HelpAction))
        positional = not action.option_strings and action.nargs not in (argparse.OPTIONAL, argparse.ZERO_OR_MORE)
        if (flag or positional or action.required or action.default is argparse.SUPPRESS
                or "default" in text.lower()):
            return text
        return f"{text} (default: %(default)s)"


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line on stderr (``<prog>: error: <message> (see
    --help)``), exit code 2; subcommand parsers are of the same class."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    from pedx_graph import __version__

    parser = OneLineParser(prog="pedx-graph", description="pedx-graph: metric 3D pedestrian body models from "
                                                          "stereo 2D labels and LiDAR (factor graphs).",
                           formatter_class=HelpFormatter)
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}",
                        help="print the version and exit")
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    parser.add_argument("--debug", action="store_true", help="show the traceback of an error (also after COMMAND)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:      # command not written yet
                continue
            raise
        module.register(sub)
    for command in sub.choices.values():     # --debug also after the command, without overriding the top one
        command.formatter_class = HelpFormatter
        command.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                             help="show the traceback of an error")
    return parser


def error_line(exc: BaseException) -> str:
    """One line saying what went wrong: the project's errors name the file and field or the config key;
    an OSError its path; anything else its type (an internal error, with ``--debug`` for the traceback)."""
    from pedx_graph.config import ConfigError
    from pedx_graph.data.types import DataFormatError

    if isinstance(exc, OSError) and exc.strerror:
        paths = " -> ".join(str(p) for p in (exc.filename, exc.filename2) if p is not None)
        text = f"{paths}: {exc.strerror}" if paths else exc.strerror
    else:
        text = str(exc).strip() or type(exc).__name__
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    text = lines[0] if lines else type(exc).__name__
    known = (ConfigError, DataFormatError, OSError, ValueError)
    if not isinstance(exc, known) or type(exc) is ValueError and not lines:
        text = f"internal error: {type(exc).__name__}: {text} (run with --debug for the traceback)"
    return text


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:                   # usage error (2) or --help (0)
        return exc.code if isinstance(exc.code, int) else 2
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s")
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        if args.debug:
            raise
        print("pedx-graph: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:                    # noqa: BLE001 - every error ends in one line (--debug: traceback)
        if args.debug:
            raise
        print(f"pedx-graph: error: {error_line(exc)}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
