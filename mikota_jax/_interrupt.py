"""Ctrl-C in the command line (``python -m mikota_jax``, ``mikota-jax``): one line on stderr and
exit code 130, at any moment of a run, the imports before it included.

Python runs its own SIGINT handler only between bytecodes, so the main thread, waiting in XLA,
acted on it only when the computation ended (more than 10 minutes at n = 3000).
Python's C-level handler still writes the signal number to a wakeup pipe at once; a watcher
thread reads it and ends the process with exit code 130. ``results.json`` is written atomically,
so an interrupted run leaves none.

Both entry points import the package first (JAX and the rest: about 2 s), before any code of the
command line runs, so ``mikota_jax/__init__.py`` installs the handler before it imports JAX when
the process is the command line (``is_command_line``); ``app.cli.main`` installs it again (once
per process counts). Standard library only: this module is imported before JAX.
"""

import os
import signal
import sys
import threading
from pathlib import Path

MESSAGE = "interrupted: stopped, nothing more written"
SCRIPTS = ("mikota-jax", "mikota-jax.exe", "mikota-jax-script.py")  # the console script's names
_installed = []


def is_command_line() -> bool:
    """Whether this process is the command line, asked while the package is imported: the
    ``mikota-jax`` console script, or ``python -m mikota_jax`` (``runpy`` imports the package
    while ``sys.argv[0]`` is ``"-m"``; ``sys.orig_argv`` names the module)."""
    first = sys.argv[0] if sys.argv else ""
    if first != "-m":
        return Path(first).name in SCRIPTS
    args = list(getattr(sys, "orig_argv", ()))
    return "-mmikota_jax" in args or any(
        a == "-m" and args[i + 1:i + 2] == ["mikota_jax"] for i, a in enumerate(args))


def exit_on_interrupt() -> None:
    """From now on, SIGINT prints ``MESSAGE`` and ends the process with exit code 130 (once per
    process; outside the main thread, where signals cannot be caught, nothing is installed)."""
    if _installed or threading.current_thread() is not threading.main_thread():
        return
    read, write = os.pipe()
    os.set_blocking(write, False)
    signal.set_wakeup_fd(write, warn_on_full_buffer=False)
    # no KeyboardInterrupt in the main thread (its traceback would race the watcher's exit)
    signal.signal(signal.SIGINT, lambda signum, frame: None)

    def watch():
        while True:
            received = os.read(read, 16)
            if signal.SIGINT in received:
                os.write(2, (MESSAGE + "\n").encode())
                os._exit(130)

    threading.Thread(target=watch, name="mikota_jax-interrupt", daemon=True).start()
    _installed.append(True)
