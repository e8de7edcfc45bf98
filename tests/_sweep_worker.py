"""One process of the two-process ``jax.distributed`` sweep in test_sweep.py:
``python _sweep_worker.py PROCESS_ID PORT OUT.npy``."""

import sys

import jax

process, port, out = int(sys.argv[1]), sys.argv[2], sys.argv[3]
jax.distributed.initialize(coordinator_address=f"localhost:{port}", num_processes=2,
                           process_id=process)

import numpy as np  # noqa: E402
from _sweep_scene import function, points  # noqa: E402

import mikota_jax as mj  # noqa: E402

assert jax.process_count() == 2 and len(jax.devices()) == 2 and len(jax.local_devices()) == 1
np.save(out, mj.sweep(function(), points(), chunk_size=4, progress=False))
