"""``python -m mikota_jax``: the command line, ``mikota_jax.app.cli``."""
from mikota_jax.app.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
