"""The ``semcityloc`` command (``cli.main``); ``entry`` is its console script (``pyproject.toml``).

Why ``entry`` lives here and not in ``cli.main``: a console script imports the module that holds its
function before it calls it, and ``cli.main`` takes over a second to import (numba, every command). A
Ctrl-C in that second came before ``main``'s ``try`` and printed a ``KeyboardInterrupt`` traceback; this
module imports next to nothing, and ``entry`` imports the CLI inside its ``try``.
"""

from __future__ import annotations

import os
import signal
import sys

INTERRUPTED = 130  # the exit status of a command ended by Ctrl-C (128 + SIGINT), as a shell reports it
TERMINATED = 143  # ended by SIGTERM (128 + 15): ``timeout``, a scheduler, ``kill``
READER_GONE = 141  # stdout's reader closed it (``semcityloc ... | head``): 128 + SIGPIPE, as other tools end


_CONSOLE = False  # set by ``entry``: this process is the ``semcityloc`` command, its signals are its own


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the command is so that it unwinds as a Ctrl-C does (locks released, temporary
    files removed, the kept work said) instead of dying silently mid-write."""


def _terminate(signum: int, frame: object) -> None:
    raise Terminated


def interrupted(exc: BaseException | None = None) -> int:
    """Say in one line on stderr that the command was interrupted (Ctrl-C) or terminated (SIGTERM);
    returns ``INTERRUPTED`` or ``TERMINATED``. In the console script, further signals are ignored from here
    on: a second Ctrl-C while the interpreter exits printed a ``KeyboardInterrupt`` traceback from
    ``threading._shutdown`` (a test calling ``main`` in-process keeps its own signals)."""
    if _CONSOLE:
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, signal.SIG_IGN)
    if isinstance(exc, Terminated):
        print("semcityloc: terminated (SIGTERM)", file=sys.stderr)
        return TERMINATED
    print("semcityloc: interrupted", file=sys.stderr)
    return INTERRUPTED


def entry() -> int:
    """The ``semcityloc`` console script: ``cli.main.main`` with the CLI imported inside the ``try``, so a
    Ctrl-C wherever it lands (the imports, the arguments, the work) is one line and exit 130, never a
    traceback; a SIGTERM likewise (``Terminated``), exit 143; stdout closed by its reader (``| head``) ends
    quietly with 141, not a ``BrokenPipeError`` traceback."""
    global _CONSOLE
    _CONSOLE = True
    signal.signal(signal.SIGTERM, _terminate)
    try:
        # lazy: the whole CLI (numba, every command) takes over a second to import, so inside the try
        from semcityloc.cli.main import main

        return main()
    except KeyboardInterrupt as exc:
        return interrupted(exc)
    except BrokenPipeError:  # the reader of stdout went away (``| head``): end quietly, as ``cat`` does
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # the exit's flush must not raise
        return READER_GONE
