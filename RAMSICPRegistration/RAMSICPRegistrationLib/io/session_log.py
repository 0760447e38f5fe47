"""The navigation session's log: what happened, in order, in one JSON file beside the autosaved point lists.

The controller records the events a later reader must be able to find (a registration applied or accepted, a
checkpoint stored, checked, or dropped, and each checkpoint alarm) in ``session_log.json`` in the autosave folder
(``ramsicp web --output``; in Slicer the module's autosave folder), next to ``ProbePoints.mrk.json`` and the other
lists collected. The file is rewritten whole at every event (``io.atomic_files``, flushed to the disk), so it is
always a complete JSON document::

    {"format": "ramsicp-session-log", "version": 1,
     "events": [{"time": "2026-12-02T10:15:03.120+00:00", "event": "checkpoint-checked", "label": "C1",
                 "distance_mm": 1.02, "limit_mm": 0.6, "alarm": true, ...}, ...]}

Times are UTC, ISO 8601 with milliseconds; distances in mm; positions in reference coordinates unless the field's
name says otherwise. A controller started on a folder that holds a log goes on appending to it; a log it cannot
read is kept under another name (``session_log.json.unreadable-<time>``), never overwritten.
"""

import json
import logging
from datetime import datetime, timezone
from pathlib import Path

from .atomic_files import atomic_path

logger = logging.getLogger(__name__)

LOG_NAME = "session_log.json"
FORMAT = "ramsicp-session-log"
VERSION = 1


def read_session_log(path):
    """The events (list of dicts, oldest first) of a session log file or of the folder holding one.

    Raises:
        ValueError: no such file, not JSON, or not a session log (the message says which).
    """
    path = Path(path)
    if path.is_dir():
        path = path / LOG_NAME
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ValueError(f"{path}: no session log there") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ValueError(f"{path}: not a readable session log ({error})") from None
    if not isinstance(document, dict) or document.get("format") != FORMAT:
        raise ValueError(f"{path}: not a session log (its 'format' is not {FORMAT!r})")
    events = document.get("events")
    if not isinstance(events, list) or not all(isinstance(e, dict) and "event" in e for e in events):
        raise ValueError(f"{path}: its 'events' are not a list of events")
    return events


class SessionLog:
    """Events of one navigation session, written to ``directory``/``session_log.json`` at each ``record`` (kept in
    memory only when ``directory`` is None)."""

    def __init__(self, directory=None):
        self.path = None if directory is None else Path(directory) / LOG_NAME
        self.events = []
        if self.path is not None and self.path.exists():
            try:
                self.events = read_session_log(self.path)
            except ValueError as error:
                kept = self.path.with_name(f"{LOG_NAME}.unreadable-{datetime.now():%Y%m%d-%H%M%S}")
                try:
                    self.path.replace(kept)
                    logger.warning("%s; kept as %s, a new log begins", error, kept)
                except OSError as move_error:  # a read-only folder must not stop navigation: the log stays in memory
                    logger.error("%s; it cannot be set aside (%s): this session is logged in memory only", error,
                                 move_error)  # fmt: skip
                    self.path = None

    def record(self, event, **fields):
        """Add an event (its kind, e.g. 'checkpoint-checked', and JSON-ready fields) and write the log; returns the
        event (a dict). A failed write is logged, never raised: the workflow goes on, the event stays in memory
        and is written with the next one."""
        entry = {"time": datetime.now(timezone.utc).isoformat(timespec="milliseconds"), "event": event, **fields}
        self.events.append(entry)
        if self.path is not None:
            try:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                document = {"format": FORMAT, "version": VERSION, "events": self.events}
                with atomic_path(self.path, durable=True) as temporary:
                    Path(temporary).write_text(json.dumps(document, indent=1), encoding="utf-8")
            except OSError as error:
                logger.error("the session log %s could not be written: %s", self.path, error)
        return entry
