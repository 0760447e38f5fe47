"""A host name's IPv4 address, looked up without ever blocking the caller (Slicer's GUI thread).

An IPv4 literal is its own address. A name is looked up by ``socket.gethostbyname`` in a daemon thread, because a
lookup can take seconds (a DNS server that does not answer). Inside Slicer, PythonQt keeps Python's lock while
Qt's event loop waits, so that thread only advances while the GUI thread runs Python; it needs the lock only to
start and to store its answer (the lookup itself releases it), so a timer polling every 20 ms gets the answer a
few polls later (``Testing/test_slicer_host.py`` measures it under that emulation). The tracker receiver and the
robot link both use it.
"""

import ipaddress
import socket
import threading


class HostLookup:
    """The address of ``host``: ``address`` (str) once known, ``error`` (one line) when the lookup failed, both
    None while it runs. A failed lookup is not retried here: make a new HostLookup (the network may come back)."""

    def __init__(self, host):
        self.host = str(host).strip()
        self.address = None
        self.error = None
        try:
            self.address = str(ipaddress.IPv4Address(self.host))
            return
        except ValueError:
            pass
        answer = self._answer = {}

        def look_up():
            try:
                answer["address"] = socket.gethostbyname(self.host)
            except (OSError, UnicodeError) as error:
                answer["error"] = f"cannot resolve the host name {self.host!r} ({error})"

        threading.Thread(target=look_up, name=f"look up {self.host}", daemon=True).start()

    @property
    def done(self):
        """True once the address or the error is known (copied from the lookup thread's answer)."""
        if self.address is None and self.error is None:
            self.address = self._answer.get("address")
            self.error = self._answer.get("error")
        return self.address is not None or self.error is not None
