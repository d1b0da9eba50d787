"""``python -m semcityloc``: the ``semcityloc`` command, through the console script's ``cli.entry`` (a
Ctrl-C while the CLI imports is one line and exit 130, as with the installed script)."""

from __future__ import annotations

import sys

from semcityloc.cli import entry

if __name__ == "__main__":
    sys.exit(entry())
