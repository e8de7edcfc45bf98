"""``python -m mikota_jax``: the command line, ``mikota_jax.app.cli``.

Ctrl-C stops a run within a moment, also in the middle of a long compiled computation: Python runs
its own SIGINT handler only between bytecodes, so the main thread, waiting in XLA, acted on it
only when the computation ended (more than 10 minutes at n = 3000, issue 18). Python's C-level
handler still writes the signal number to a wakeup pipe at once; a watcher thread reads it and
ends the process with exit code 130. ``results.json`` is written atomically, so an interrupted run
leaves none.
"""

import os
import signal
import threading


def _exit_on_interrupt() -> None:
    read, write = os.pipe()
    os.set_blocking(write, False)
    signal.set_wakeup_fd(write, warn_on_full_buffer=False)
    # no KeyboardInterrupt in the main thread (its traceback would race the watcher's exit)
    signal.signal(signal.SIGINT, lambda signum, frame: None)

    def watch():
        while True:
            received = os.read(read, 16)
            if signal.SIGINT in received:
                os.write(2, b"interrupted: stopped, nothing more written\n")
                os._exit(130)

    threading.Thread(target=watch, name="mikota_jax-interrupt", daemon=True).start()


if __name__ == "__main__":
    _exit_on_interrupt()
    from mikota_jax.app.cli import main

    raise SystemExit(main())
