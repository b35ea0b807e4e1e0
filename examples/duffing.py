"""A Duffing oscillator (a mass on a hardening spring) for a nonlinear chatterspec model file.

    m x'' + c x' + k x + k3 x^3 = F          states: position x (m), velocity x' (m/s); input: force F (N)

`duffing_model.toml` names these functions (`f = "duffing.py:g"`, `jacobian = "duffing.py:g_jacobian"`,
`form = "continuous"`: chatterspec steps x' = g(x, u) by explicit Euler at the file's dt). Both are
batched: x has shape (..., 2), u (..., 1) or (1,); the parameters arrive as keyword arguments from the
file's [dynamics.parameters] table (SI units).
"""

import numpy as np


def g(x, u, *, mass, stiffness, cubic, damping):
    """x' = g(x, u): velocity and acceleration (m/s, m/s^2)."""
    pos, vel = x[..., 0], x[..., 1]
    acc = (u[..., 0] - damping * vel - stiffness * pos - cubic * pos**3) / mass
    vel, acc = np.broadcast_arrays(vel, acc)
    return np.stack([vel, acc], axis=-1)


def g_input(x, u, *, mass, stiffness, cubic, damping):
    """dg/du at one point, shape (2, 1): the force enters the acceleration as 1 / mass."""
    return np.array([[0.0], [1.0 / mass]])


def g_jacobian(x, u, *, mass, stiffness, cubic, damping):
    """dg/dx, shape (..., 2, 2)."""
    pos = x[..., 0]
    J = np.zeros((*np.broadcast_shapes(x.shape[:-1], np.shape(u)[:-1]), 2, 2))
    J[..., 0, 1] = 1.0
    J[..., 1, 0] = -(stiffness + 3.0 * cubic * pos**2) / mass
    J[..., 1, 1] = -damping / mass
    return J
