"""The small sweep shared by test_sweep.py and its subprocesses (several devices, processes)."""

import numpy as np

import mikota_jax as mj

TOML = """
[chain]
n = 12
[[damper]]
position = 5.5
coefficient = 0.8
[initial]
displacement = { 3 = 1.0 }
[time]
end = 3.0
step = 0.05
[solver]
method = "dopri8"
rtol = 1e-8
[output]
dofs = [6]
"""


def function(output: str = "energy"):
    return mj.SceneFunction(mj.app.load_scene(TOML), output)


def points():
    return mj.grid(positions=np.linspace(1.0, 12.0, 4)[:, None],
                   coefficients=np.geomspace(0.1, 10.0, 3)[:, None])
