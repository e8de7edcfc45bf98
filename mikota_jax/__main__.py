"""``python -m mikota_jax``: the command line, ``mikota_jax.app.cli.main``, as the ``mikota-jax``
console script runs it (Ctrl-C: one line and exit code 130, see ``mikota_jax._interrupt``)."""

from mikota_jax.app.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
