"""What the commands share about the console: standard output that survives a reader who leaves, progress bars
for long runs (tqdm, on a terminal only) and numbers in one line."""

import os
import sys
import weakref

_open_bars = weakref.WeakSet()
#: What a bar shows: the step, how far, and the time spent and left (no rate: the steps are not alike).
_BAR = "{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} [{elapsed}<{remaining}]"


class ReaderMayLeave:
    """Standard output for a reader that may stop reading (``ramsicp register ... | head``).

    When the pipe breaks, the rest of the output goes to ``os.devnull``, as Python's documentation recommends for
    SIGPIPE, and the command goes on: its files are still written and its exit code is its own, with no traceback
    and no "Broken pipe" message.
    """

    def __init__(self, stream):
        self.stream = stream

    def write(self, text):
        try:
            return self.stream.write(text)
        except BrokenPipeError:
            self._to_devnull()
            return len(text)

    def flush(self):
        try:
            self.stream.flush()
        except BrokenPipeError:
            self._to_devnull()

    def _to_devnull(self):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, self.stream.fileno())
        os.close(devnull)

    def __getattr__(self, name):
        return getattr(self.stream, name)


class Progress:
    """The library's ``progress(step, done, total)`` callback drawn as a tqdm bar per step on standard error, only
    when it is a terminal (a log file or a pipe gets nothing)."""

    def __init__(self, stream=None):
        self.stream = stream if stream is not None else sys.stderr
        self.bar = None

    def __call__(self, step, done, total):
        if not self.stream.isatty():
            return
        if self.bar is None or self.bar.desc != step or done < self.bar.n:
            self.close()
            from tqdm import tqdm

            self.bar = tqdm(desc=step, total=total, file=self.stream, dynamic_ncols=True, bar_format=_BAR)
            _open_bars.add(self)
        self.bar.total = total
        self.bar.update(done - self.bar.n)
        if done >= total:
            self.close()

    def close(self):
        if self.bar is not None:
            self.bar.close()
            self.bar = None


def close_progress_bars():
    """End every bar still drawn (an interrupted run), so that the next line starts on a line of its own."""
    for progress in list(_open_bars):
        progress.close()


def decimals(values):
    """Numbers with 2 decimals, space-separated: '0.12 3.40 5.00'."""
    return " ".join(f"{value:.2f}" for value in values)
