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


def test_cache_info_says_when_its_folder_cannot_be_used(tmp_path):
    """A regular file, or a link to nothing, as CASEST_CACHE_DIR: exit 1 with the cause, not '0 functions'."""
    import os
    import subprocess
    import sys

    plain = tmp_path / "plain"
    plain.write_text("")
    dangling = tmp_path / "dangling"
    dangling.symlink_to(tmp_path / "missing")
    for folder, cause in ((plain, "it is a file, not a folder"), (dangling, "which does not exist")):
        run = subprocess.run([sys.executable, "-m", "casest", "cache", "info"], capture_output=True, text=True,
                             env={**os.environ, "CASEST_CACHE_DIR": str(folder)}, timeout=120)
        assert run.returncode == 1 and cause in run.stderr, run.stderr
