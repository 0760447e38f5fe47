"""What the package's commands (``ramsicp``, ``ramsicp-tracker-server``) share about their arguments: a mistake is
one line, which option and what is wrong, and exit code ``EXIT_BAD_INPUT``, as every other error they report."""

import argparse

#: Exit code of a command given bad input (an argument, a file), said in one line before any work.
EXIT_BAD_INPUT = 2


class OneLineParser(argparse.ArgumentParser):
    """argparse, but an argument error is one line (no usage block) pointing to ``--help``, exit ``EXIT_BAD_INPUT``.

    Sub-command parsers made by ``add_subparsers().add_parser`` are of this class too.
    """

    def error(self, message):
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see {self.prog} --help)\n")
