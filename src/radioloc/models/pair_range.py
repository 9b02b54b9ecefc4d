"""Ranges between two unknown nodes of a network: the joint state and its measurement model.

Cooperative (network) positioning estimates every node at once: the state stacks the
positions of the ``K`` nodes, ``x = [x_1; ...; x_K]`` (paper 000, eq. (13)), and a range
between nodes ``i`` and ``j`` reads two blocks of it, ``h(x) = |x_i - x_j|`` (eq. (14)).

- :class:`NetworkLayout`: a :class:`~radioloc.models.measurement.StateLayout` whose
  ``position`` component holds the ``K`` stacked positions, ``(..., K D)`` node by node.
- :class:`PairContext`: a :class:`~radioloc.models.measurement.Context` whose ``pairs``
  name the two nodes of each row; a second index of ``-1`` makes the row a range to the
  known point ``points[row]`` (an anchor), so anchor and inter-node ranges mix freely.
- :class:`PairRangeModel`: the range model over those rows, with the analytic Jacobian
  (``+u`` in node ``i``'s block, ``-u`` in node ``j``'s, ``u = (x_i - x_j) / |x_i - x_j|``,
  eq. (17) with the sign of the second block corrected) and any noise
  :class:`~radioloc.models.ranging.RangeModel` takes.

Any estimator that runs on :meth:`StateLayout.measure` (the generic extended Kalman
filter's update) takes these rows unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radioloc.core.errors import InputError
from radioloc.core.validation import check_dtype
from radioloc.models.measurement import Context, StateLayout, gaussian_logpdf
from radioloc.models.ranging import GaussianRange, RangeModel

__all__ = ["NetworkLayout", "PairContext", "PairRangeModel", "packet_context"]


@dataclass(frozen=True)
class NetworkLayout(StateLayout):
    """A state layout holding the stacked positions of ``nodes`` nodes (eq. (13)).

    ``position`` is ``(..., nodes * dim)``: ``[x_1, y_1, x_2, y_2, ...]``; velocity and
    acceleration, when present, are stacked the same way.

    Parameters
    ----------
    dim, order, clock, n_bias : see :class:`~radioloc.models.measurement.StateLayout`
    nodes : int
        Number of nodes ``K`` (>= 1).

    Examples
    --------
    >>> NetworkLayout(dim=2, nodes=6).size
    12
    """

    nodes: int = 1

    def __post_init__(self) -> None:
        super().__post_init__()
        if int(self.nodes) != self.nodes or self.nodes < 1:
            raise InputError(f"nodes: must be a whole number >= 1, got {self.nodes!r}")

    @property
    def sizes(self) -> dict[str, int]:
        """Size of each component present, in state order."""
        out = dict(super().sizes)
        for name in ("position", "velocity", "acceleration"):
            if name in out:
                out[name] *= int(self.nodes)
        return out

    @property
    def motion_size(self) -> int:
        """Length of the kinematic part (every node's position, velocity, acceleration)."""
        return super().motion_size * int(self.nodes)

    def kinematic(self, matrix: np.ndarray) -> np.ndarray:
        """One node's motion matrix applied to every node: entry ``(c, d), (c', d')`` of
        the node (``C`` = order + 1 components of ``D`` coordinates) lands at
        ``(c, k, d), (c', k, d')`` of the stacked state, nodes independent.

        Parameters
        ----------
        matrix : ndarray, shape (..., C D, C D)

        Returns
        -------
        ndarray, shape (..., C K D, C K D)
        """
        C, D, K = self.order + 1, self.dim, int(self.nodes)
        m = np.asarray(matrix, dtype=float)
        blocks = m.reshape(m.shape[:-2] + (C, D, C, D))
        out = np.einsum("...adbe,kl->...akdble", blocks, np.eye(K))
        return out.reshape(m.shape[:-2] + (C * K * D, C * K * D))

    def position_moments(self, mean: np.ndarray, cov: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray]:
        """Every node's position and its own covariance block.

        Parameters
        ----------
        mean : ndarray, shape (..., n)
        cov : ndarray, shape (..., n, n)

        Returns
        -------
        position : ndarray, shape (..., K, D)
        covariance : ndarray, shape (..., K, D, D)
        """
        K, D = int(self.nodes), self.dim
        pos = mean[..., :K * D].reshape(mean.shape[:-1] + (K, D))
        c = cov[..., :K * D, :K * D].reshape(cov.shape[:-2] + (K, D, K, D))
        return pos, np.einsum("...kdke->...kde", c)


@dataclass(frozen=True)
class PairContext(Context):
    """Rows between two nodes of a :class:`NetworkLayout` state.

    Attributes
    ----------
    pairs : ndarray of int, shape (..., m, 2)
        ``pairs[..., r, :] = (i, j)``: row ``r`` is the range between node ``i`` and node
        ``j`` (indices into the stacked state, ``i != j``); ``j = -1``: between node ``i``
        and the known point ``points[..., r, :]``. Leading axes broadcast against the
        state's batch axes (a different pair per run).
    points : ndarray, shape (..., m, D)
        The known end of the rows with ``j = -1``; also fixes the position dimension ``D``
        (the entries of the other rows are not read).
    std : ndarray, shape (..., m), optional
        A per-row standard deviation that overrides the model's (NaN: the model's).

    Other fields are those of :class:`~radioloc.models.measurement.Context`; ``height_m``
    is not supported.
    """

    pairs: np.ndarray | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.pairs is None:
            raise InputError("pairs: a PairContext needs the two nodes of every row")
        p = check_dtype(self.pairs, "pairs")
        m = self.rows
        if p.shape[-2:] != (m, 2) or not np.issubdtype(p.dtype, np.integer):
            raise InputError(f"pairs: expected integers of shape (..., {m}, 2) (one node pair "
                             f"per row), got {p.dtype} of shape {p.shape}")
        if np.any(p[..., 0] < 0) or np.any(p[..., 1] < -1):
            raise InputError("pairs: node indices must be >= 0 (-1 only as the second, "
                             "for a known point)")
        same = p[..., 0] == p[..., 1]
        if np.any(same):
            idx = tuple(int(i) for i in np.argwhere(same)[0])
            raise InputError(f"pairs: row {idx} joins node {int(p[idx + (0,)])} to itself")
        if self.height_m is not None:
            raise InputError("height_m: not supported for ranges between nodes")
        object.__setattr__(self, "pairs", p.astype(np.intp, copy=False))

    def take(self, rows: np.ndarray) -> "PairContext":
        """The context of a subset of rows (see :meth:`Context.take`).

        Parameters
        ----------
        rows : ndarray
            An index array or a boolean mask over the rows.

        Returns
        -------
        PairContext
        """
        sub = super().take(rows)
        r = np.asarray(rows)
        pairs = np.compress(r, self.pairs, axis=-2) if r.dtype == bool \
            else np.take(self.pairs, r, axis=-2)
        return PairContext(points=sub.points, index=sub.index, reference=sub.reference,
                           reference_index=sub.reference_index, std=sub.std, pairs=pairs)


def _ends(position: np.ndarray, context: Context) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                          np.ndarray]:
    """Both ends of every row, ``x_i`` and ``x_j`` (or the row's known point), ``(..., m, D)``,
    and the node indices ``i``, ``j`` ``(m,)`` or, with per-state pairs, broadcast to the
    states' batch ``(..., m)``."""
    if not isinstance(context, PairContext):
        raise InputError(f"context: a PairRangeModel needs a PairContext (the nodes of each "
                         f"row), got {type(context).__name__}")
    pos = np.asarray(position, dtype=float)
    D = context.points.shape[-1]
    if pos.ndim < 1 or pos.shape[-1] % D:
        raise InputError(f"state['position']: {pos.shape[-1:]} entries are not whole "
                         f"{D}-D node positions (context.points is {D}-D)")
    K = pos.shape[-1] // D
    i, j = context.pairs[..., 0], context.pairs[..., 1]
    if np.any(i >= K) or np.any(j >= K):
        raise InputError(f"context.pairs: node {int(max(i.max(), j.max()))} is outside the "
                         f"{K} nodes of the state")
    nodes = pos.reshape(pos.shape[:-1] + (K, D))
    if i.ndim == 1:                                   # the same pairs for every state
        xi, xj = nodes[..., i, :], nodes[..., np.maximum(j, 0), :]
    else:
        batch = np.broadcast_shapes(nodes.shape[:-2], i.shape[:-1])
        nodes = np.broadcast_to(nodes, batch + (K, D))
        i = np.broadcast_to(i, batch + i.shape[-1:])
        j = np.broadcast_to(j, batch + j.shape[-1:])
        xi = np.take_along_axis(nodes, i[..., None], axis=-2)
        xj = np.take_along_axis(nodes, np.maximum(j, 0)[..., None], axis=-2)
    xj = np.where((j >= 0)[..., None], xj, context.points)
    return xi, xj, i, j


@dataclass(frozen=True)
class PairRangeModel(RangeModel):
    """Range between two nodes of a network state: ``h(x) = |x_i - x_j|`` (eq. (14)).

    The rows come in a :class:`PairContext`; the state is laid out by a
    :class:`NetworkLayout`. Noise as in :class:`~radioloc.models.ranging.RangeModel`
    (``std_m`` or ``noise``); per-anchor bias is not supported.

    Parameters
    ----------
    std_m : float, optional
        Standard deviation of a Gaussian range error, metres.
    noise : GaussianRange or LosNlosRange, optional
        The range-error model (give this or ``std_m``).
    min_distance_m : float
        Distances are floored here so the Jacobian stays finite when two estimates coincide.

    Examples
    --------
    >>> import numpy as np
    >>> layout = NetworkLayout(dim=2, nodes=3)
    >>> ctx = PairContext(points=np.zeros((2, 2)), pairs=np.array([[1, 0], [2, 0]]))
    >>> x = np.array([0.0, 0.0, 3.0, 4.0, 6.0, 8.0])
    >>> z_hat, H = layout.measure(PairRangeModel(std_m=1.0), x, ctx)
    >>> z_hat.tolist(), H[0].round(1).tolist()
    ([5.0, 10.0], [-0.6, -0.8, 0.6, 0.8, 0.0, 0.0])
    """

    min_distance_m: float = 1e-9

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.anchor_bias:
            raise InputError("anchor_bias: not supported by PairRangeModel")

    def predict_with_jacobian(self, state, context: Context
                              ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """:meth:`predict` and :meth:`jacobian` of the pair (not :class:`RangeModel`'s
        shared geometry to known points)."""
        return self.predict(state, context), self.jacobian(state, context)

    def predict(self, state, context: Context) -> np.ndarray:
        xi, xj, _, _ = _ends(state["position"], context)
        return np.sqrt(np.sum((xi - xj) ** 2, axis=-1))

    def jacobian(self, state, context: Context) -> dict[str, np.ndarray]:
        xi, xj, i, j = _ends(state["position"], context)
        diff = xi - xj
        d = np.sqrt(np.sum(diff ** 2, axis=-1))
        u = diff / np.maximum(d, self.min_distance_m)[..., None]             # (..., m, D)
        D = u.shape[-1]
        K = np.shape(state["position"])[-1] // D
        # +u in node i's block, -u in node j's (a known point's rows: a spare block K)
        J = np.zeros(u.shape[:-1] + (K + 1, D))
        i, j = np.broadcast_to(i, u.shape[:-1]), np.broadcast_to(np.where(j >= 0, j, K), u.shape[:-1])
        np.put_along_axis(J, i[..., None, None], u[..., None, :], axis=-2)
        np.put_along_axis(J, j[..., None, None], -u[..., None, :], axis=-2)
        return {"position": J[..., :K, :].reshape(u.shape[:-1] + (K * D,))}

    def logpdf(self, z, state, context: Context) -> np.ndarray:
        z_hat = self.predict(state, context)
        z = check_dtype(z, "z").astype(float, copy=False)
        try:
            ok = z.shape[-1:] == z_hat.shape[-1:] and bool(np.broadcast_shapes(z.shape, z_hat.shape))
        except ValueError:
            ok = False
        if not ok:
            raise InputError(f"z: shape {z.shape} does not match the rows predicted from state "
                             f"and context {z_hat.shape}")
        if context.std is not None or isinstance(self.noise, GaussianRange):
            r = z - z_hat - self.noise_mean(context)
            lp = gaussian_logpdf(r, self.std(context))
        else:
            lp = self.noise.logpdf(z, z_hat)
        return np.where(np.isnan(lp), 0.0, lp)


def packet_context(master: np.ndarray, nodes: int, dim: int = 2) -> tuple[PairContext, np.ndarray]:
    """The rows of a master's packet (eq. (15)): node ``p`` to master ``k`` for every
    ``p != k``, in node order.

    Parameters
    ----------
    master : ndarray of int, shape (...)
        The master node ``k`` (per run).
    nodes : int
        ``K``.
    dim : int
        Position dimension.

    Returns
    -------
    context : PairContext
        ``pairs`` of shape ``(..., K - 1, 2)``.
    others : ndarray of int, shape (..., K - 1)
        The node ``p`` of each row (to pick the packet's ranges out of a length-``K`` row).
    """
    k = np.asarray(master, dtype=np.intp)
    p = np.arange(nodes - 1)
    others = p + (p >= k[..., None])
    pairs = np.stack([others, np.broadcast_to(k[..., None], others.shape)], axis=-1)
    return PairContext(points=np.zeros((nodes - 1, dim)), pairs=pairs), others

