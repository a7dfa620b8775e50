"""The catheter rod's pose as one compiled call (``rod_statics.RodStatics.pose``).

``rod_pose`` is ``RodStatics.pose_reference``'s arithmetic, operation for operation, from the
joints' cosines and sines on: the elementary rotations about x, y and z of every free joint, their
product along the chain (3 x 3 products by numba's ``@``, which calls the same BLAS ``dgemm`` as
numpy's ``matmul``: the same floats, checked by the tests), the nodes as the running sum of the
joints' ends, and each node's Jacobian column by column as the joint axis crossed with the lever
from the joint (``vectors.cross``'s products and differences in its order). The cosines and sines
stay numpy's (``np.cos``, ``np.sin``), computed by the caller, so nothing depends on which libm
numba links. The reference's 60 matrix products a pose at 20 free joints cost 1-2 us of Python
each; the solver asks for a pose at every iterate and every line-search trial
(docs/performance.md 36).
"""

from __future__ import annotations

import numpy as np

from ballchain.drake_models.kernels._common import kernel


@kernel
def rod_pose(R0, c, s, p, h, last_step):
    """The rod's free nodes and Jacobians for f = len(c) >= 1 free joints.

    Args:
        R0: (3, 3) the frame at the first free joint (the exit's, turned by the shaft's twist).
        c, s: (f, 3) the joints' angles' cosines and sines (about x, y, z).
        p: (3,) the first free joint's position [m].
        h: the segment length [m]; last_step: the last segment's step to the tip sphere's centre [m].

    Returns:
        (nodes (f + 1, 3), J (f + 1, 3 f, 3): node by joint axis, the reference's layout before its
        transpose, axes (3 f, 3), R_tip (3, 3)).
    """
    f = c.shape[0]
    R = np.ascontiguousarray(R0)
    axes = np.zeros((3 * f, 3))
    ends = np.zeros((f, 3))
    rot = np.zeros((3, 3))
    for i in range(f):
        for k in range(3):
            a = (k + 1) % 3
            b = (k + 2) % 3
            rot[:, :] = 0.0
            rot[k, k] = 1.0
            rot[a, a] = c[i, k]
            rot[b, b] = c[i, k]
            rot[a, b] = -s[i, k]
            rot[b, a] = s[i, k]
            axes[3 * i + k, :] = R[:, k]
            R = R @ rot
        ends[i, :] = R[:, 2]
    m = f + 1
    nodes = np.zeros((m, 3))
    nodes[0, :] = p
    for i in range(f):
        step = h if i < f - 1 else last_step
        for d in range(3):
            nodes[i + 1, d] = nodes[i, d] + ends[i, d] * step
    J = np.zeros((m, 3 * f, 3))
    for n in range(m):
        for col in range(3 * f):
            j = col // 3
            if n <= j:  # a joint moves only the nodes after it
                continue
            a0, a1, a2 = axes[col, 0], axes[col, 1], axes[col, 2]
            l0 = nodes[n, 0] - nodes[j, 0]
            l1 = nodes[n, 1] - nodes[j, 1]
            l2 = nodes[n, 2] - nodes[j, 2]
            J[n, col, 0] = a1 * l2 - a2 * l1
            J[n, col, 1] = a2 * l0 - a0 * l2
            J[n, col, 2] = a0 * l1 - a1 * l0
    return nodes, J, axes, R
