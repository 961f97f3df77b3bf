"""The command line's surface: help text on every option, the version, the command summary.

Truth: the parser itself (every argparse action of every subcommand) and casest.__version__.
"""

import pytest


def test_every_option_has_help_and_the_version_is_printed(capsys):
    """Issue 29: help text on every option of every command, `casest --version`, `cache` in the summary."""
    import argparse

    from casest import __version__
    from casest.apps.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    silent = [(name, a.dest) for name, p in sub.choices.items() for a in p._actions if not a.help]
    assert silent == []
    assert "casest cache" in parser.description
    with pytest.raises(SystemExit) as out:
        parser.parse_args(["--version"])
    assert out.value.code == 0 and capsys.readouterr().out.strip() == f"casest {__version__}"
