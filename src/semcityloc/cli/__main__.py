"""``python -m semcityloc.cli``: the ``semcityloc`` command, as ``python -m semcityloc`` (``entry``)."""

from __future__ import annotations

import sys

from semcityloc.cli import entry

if __name__ == "__main__":
    sys.exit(entry())
