"""The exit codes of ``ramsicp``: 0 done; the others say why it stopped (also in ``ramsicp --help``)."""

from ..io.command_line import EXIT_BAD_INPUT

#: ``ramsicp ipc --markers``: every file was written, but fewer marker centres are usable than the tool has.
EXIT_TOO_FEW_MARKERS = 3
#: ``ramsicp register``: the result is printed and written, but it failed a check (``RegistrationResult.alarms``).
EXIT_ALARM = 4
#: Stopped by Ctrl-C (128 + SIGINT, as a shell reports it); no output file is left half-written.
EXIT_INTERRUPTED = 130

__all__ = ["EXIT_ALARM", "EXIT_BAD_INPUT", "EXIT_INTERRUPTED", "EXIT_TOO_FEW_MARKERS"]
