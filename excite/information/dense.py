"""The linearised problem as matrices, for export and for the tests' dense reference: the
whitened Jacobian ``J`` (sparse) with a label per row, the names of the state columns, and
:func:`marginal_dense`, the marginal computed the plain way (form J and H in full, Schur
complement with numpy) that the fast paths of :mod:`.elimination` are held to."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..factors.base import BIAS_STATE_DIM, STATE_DIM
from .problem import Problem


def jacobian(problem: Problem) -> tuple[sp.csr_matrix, list[str]]:
    """The whitened Jacobian ``J`` (sparse, columns: states then θ) and a label per row."""
    rows, cols, vals, labels = [], [], [], []
    r0 = 0
    nx = problem.n_states
    for b in problem.blocks:
        N, r = b.n_factors, b.n_rows
        rid = r0 + np.arange(N * r).reshape(N, r)
        sd, xd = problem.state_dim, b.Jx.shape[2] // b.n_states
        for a in range(b.n_states):
            c = sd * (b.first + a * b.stride)[:, None] + np.arange(xd)[None, :]
            blk = b.Jx[:, :, xd * a: xd * (a + 1)]
            rows.append(np.broadcast_to(rid[:, :, None], blk.shape).ravel())
            cols.append(np.broadcast_to(c[:, None, :], blk.shape).ravel())
            vals.append(blk.ravel())
        rows.append(np.broadcast_to(rid[:, :, None], b.Jt.shape).ravel())
        cols.append(np.broadcast_to(nx + b.cols, b.Jt.shape).ravel())
        vals.append(b.Jt.ravel())
        labels += [f"{b.name}[{k}].{i}" for k in b.first for i in range(r)]
        r0 += N * r
    rows, cols, vals = np.concatenate(rows), np.concatenate(cols), np.concatenate(vals)
    keep = vals != 0
    J = sp.csr_matrix((vals[keep], (rows[keep], cols[keep])), shape=(r0, nx + problem.n_params))
    return J, labels


def state_names(n_keyframes: int, local: bool = True, state_dim: int = STATE_DIM) -> list[str]:
    """Names of the state columns of ``J`` and ``H``, in order (see the module docstring)."""
    if local:
        comps = ["rot_x", "rot_y", "rot_z", "vel_body_x", "vel_body_y", "vel_body_z",
                 "incr_body_x", "incr_body_y", "incr_body_z"]
    else:
        comps = ["rot_x", "rot_y", "rot_z", "pos_x", "pos_y", "pos_z", "vel_x", "vel_y", "vel_z"]
    if state_dim == BIAS_STATE_DIM:
        comps += [f"{k}_bias_dev_{a}" for k in ("gyro", "accel") for a in "xyz"]
    elif state_dim > STATE_DIM:
        comps += [f"dev_{i}" for i in range(state_dim - STATE_DIM)]
    return [f"x{k}.{c}" for k in range(n_keyframes) for c in comps]


def marginal_dense(problem: Problem, gauge: bool = True) -> np.ndarray:
    """Dense reference: form J and H in full and take the Schur complement with numpy.

    With ``gauge=False`` the gauge prior is left out and ``H_xx`` pseudo-inverted instead, which
    shows that the marginal does not depend on how (or whether) the gauge is fixed.
    """
    J, _ = jacobian(problem if gauge else problem.without_gauge())
    J = J.toarray()
    H = J.T @ J
    nx = problem.n_states
    Hxx, Hxt, Htt = H[:nx, :nx], H[:nx, nx:], H[nx:, nx:]
    if gauge:
        X = np.linalg.solve(Hxx, Hxt)
    else:
        X = np.linalg.pinv(Hxx, rcond=1e-12, hermitian=True) @ Hxt
    Lam = Htt - Hxt.T @ X
    return 0.5 * (Lam + Lam.T)
