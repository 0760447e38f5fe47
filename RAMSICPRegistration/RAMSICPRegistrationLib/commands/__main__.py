"""``python -m RAMSICPRegistrationLib.commands``: the ``ramsicp`` command line."""

import sys

from . import main

if __name__ == "__main__":
    sys.exit(main())
