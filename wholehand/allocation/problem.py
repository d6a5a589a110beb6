"""The force-allocation QP of one control cycle (paper Sec. III-C), built separately from solving.

Paper form (variables ``f``: the local forces ``[f_n, f_t1, f_t2]`` of all N contacts, 3N)::

    min_f   1/2 ||G f||^2                                        residual wrench, unit weights
    s.t.    f_n,i >= 0,   |f_t1,i| + |f_t2,i| <= mu f_n,i         unilateral + friction pyramid
            sum_i f_n,i >= f_n_min                                minimum squeeze
            -tau_max <= J_act^T f_act <= tau_max                  torque limits (actuated contacts)
            -eps 1 <= N_u^T f_act <= eps 1                        actuation consistency

where ``f_act`` stacks the *world-axis* forces of the contacts on actuated links, in the
coordinates ``J_act`` acts on: ``f_act,i = wRc_i f_i`` (see :mod:`wholehand.allocation.grasp`
for frames and signs). :func:`wholehand.allocation.reference.direct_problem` builds exactly this
(plus the tie-break below).

Torque sign. ``f`` is the force of the hand on the object, so the object pushes the hand with
``-f``. A static hand needs ``tau + J^T (-f) = 0``, i.e. ``tau = J^T f``. One-joint check: a link
turning about world z through the origin, contact point at ``p = (L, 0, 0)``: ``J = dp/dq =
(0, L, 0)``. Pushing the object along +y with ``f = (0, F, 0)`` the link feels ``-F`` along y, a
moment ``-L F`` about z, which the motor holds with ``tau = +L F = J^T f``. Equivalently, by
virtual work, the motor does work ``tau dq = f . (J dq)`` on the object.

Tie-break. ``1/2 ||G f||^2`` does not fix the magnitude (every feasible scaling of a balanced
``f`` is optimal), and its Hessian ``G^T G`` has rank 6. A ridge ``reg/2 ||.||^2`` on the
variables makes the optimum unique (the smallest balanced squeeze: a symmetric antipodal pair
gets equal normal forces summing to exactly ``f_n_min``) and the Hessian positive definite. Its
price is bounded: the residual part of the objective exceeds the true optimum by at most
``reg/2 ||x*||^2`` (``x*`` the minimum-norm optimal point): below 1e-5 N^2 at the defaults
(``reg = 1e-6``, ``f_n_min = 10 N``); residual wrenches of balanced synthetic grasps come out at
1e-8..1e-6. DAQP, OSQP and PIQP were checked from ``reg = 1e-8`` to ``1e-4``.

Solved form (what :class:`AllocationQP` and :func:`~wholehand.allocation.reference.solved_problem`
carry). Two exact
reformulations make the problem cheap for a dense active-set solver:

1. Friction-pyramid edges. Per contact ``f_i = E lambda_i`` with ``lambda_i >= 0`` (4,) and
   ``E = [[1, 1, 1, 1], [mu, -mu, 0, 0], [0, 0, mu, -mu]]``. The image of ``lambda >= 0`` is
   exactly the pyramid (``f_n >= 0`` included): ``f_n = sum(lambda)``, ``|f_t1| + |f_t2| =
   mu (|l1 - l2| + |l3 - l4|) <= mu f_n``; conversely, for ``f`` in the pyramid with slack
   ``s = f_n - (|f_t1| + |f_t2|) / mu >= 0`` take ``l1,2 = max(+-f_t1, 0) / mu + s/4``,
   ``l3,4 = max(+-f_t2, 0) / mu + s/4``. Unilateral and friction become simple bounds, and the
   minimum squeeze is ``sum(lambda) >= f_n_min``.
2. Wrench splitting. A free variable ``w`` (6,) with the equality ``G E lambda - w = 0`` turns the
   objective into ``1/2 ||w||^2 + reg/2 ||lambda||^2``: a *diagonal* Hessian, so no dense
   factorisation is needed.

The tie-break is then a ridge on the edge weights (for a pure normal force ``||lambda||^2 =
f_n^2 / 4``); optimal residuals agree with the paper form up to the bound above, and the tests
check the feasible sets and optimal values against the reference forms.

The actuation-consistency basis ``N_u`` is :mod:`wholehand.allocation.null_space`.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, cast

import numpy as np
import numpy.typing as npt

from wholehand import defaults
from wholehand.allocation.base import checked_jacobians
from wholehand.allocation.grasp import wrench_map
from wholehand.allocation.kernels import consistency_rows, edge_forces, structured_terms
from wholehand.allocation.null_space import ActuationNullSpace
from wholehand.errors import ConfigError

if TYPE_CHECKING:
    from wholehand.contacts.base import ContactSet

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]

REG: float = 1e-6
"""Ridge weight of the tie-break ``reg/2 ||lambda||^2`` on the pyramid-edge weights [-]."""

N_EDGES: int = 4
"""Edges of the linearised friction pyramid per contact."""

N_WRENCH: int = 6
"""Size of the wrench ``[force; torque]``."""


def friction_edges(mu: float) -> FloatArray:
    """(3, 4) matrix ``E`` whose columns are the pyramid edges in local ``[n, t1, t2]`` axes."""
    return np.array([[1.0, 1.0, 1.0, 1.0], [mu, -mu, 0.0, 0.0], [0.0, 0.0, mu, -mu]])


def _bad(owner: str, name: str, value: object, want: str) -> ConfigError:
    return ConfigError(f"{owner}: parameter {name}={value!r} is invalid; it must be {want}")


def _checked_tau_max(owner: str, tau_max: object) -> float | FloatArray:
    """``tau_max`` as a number or a 1-D array of numbers > 0 [N*m]."""
    want = "a number or 1-D array of numbers > 0 [N*m]"
    try:
        tmax = np.array(tau_max, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise _bad(owner, "tau_max", tau_max, want) from err
    if tmax.ndim > 1 or tmax.size == 0 or np.isnan(tmax).any() or (tmax <= 0.0).any():
        raise _bad(owner, "tau_max", tau_max, want)
    return float(tmax) if tmax.ndim == 0 else tmax


def _checked_dofs(owner: str, actuated_dofs: object) -> IntArray:
    """``actuated_dofs`` (a boolean mask or unique indices >= 0) as sorted joint indices."""
    a = np.asarray(actuated_dofs)
    want = "None, a 1-D boolean mask over the joints or 1-D unique joint indices >= 0"
    if a.ndim != 1:
        raise _bad(owner, "actuated_dofs", actuated_dofs, want)
    if a.dtype == np.bool_:
        return np.flatnonzero(a).astype(np.intp)
    if not (np.issubdtype(a.dtype, np.integer) or a.size == 0):
        raise _bad(owner, "actuated_dofs", actuated_dofs, want)
    dofs = a.astype(np.intp)
    if (dofs < 0).any() or np.unique(dofs).size != dofs.size:
        raise _bad(owner, "actuated_dofs", actuated_dofs, want)
    return np.sort(dofs)


@dataclass(frozen=True)
class AllocationParams:
    """Constants of the allocation QP; see :mod:`wholehand.defaults` for their meaning."""

    mu: float = defaults.MU
    """Friction coefficient of the pyramid [-]."""
    f_n_min: float = defaults.F_N_MIN
    """Lower bound on the sum of normal forces [N]."""
    tau_max: float | FloatArray = defaults.TAU_MAX
    """Joint torque limit, scalar or (n_v,) per joint [N*m]; ``inf`` disables a joint's rows."""
    eps_margin: float = defaults.EPS_MARGIN
    """Bound on the actuation-null-space force components [N]."""
    svd_tol: float = defaults.SVD_TOL
    """Absolute singular-value tolerance deciding rank(J_act) [units of J: m/rad or -]."""
    reg: float = REG
    """Ridge weight of the tie-break [-]."""
    consistency: bool = True
    """Impose the actuation-consistency rows (False: the paper's ablation)."""
    actuated_dofs: IntArray | None = None
    """Indices of the joints whose torque this allocator commands; None: all n_v joints."""

    @classmethod
    def checked(cls, owner: str, **values: Any) -> AllocationParams:
        """Validated parameters: the given ``values`` (field names), the fields' defaults for the
        rest; an unknown name or a bad value raises :class:`ConfigError` naming ``owner``."""
        given = {f.name: f.default for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - set(given))
        if unknown:
            raise ConfigError(f"{owner}: unknown parameters {unknown}; known: {sorted(given)}")
        given.update(values)
        mu, f_n_min, tau_max = given["mu"], given["f_n_min"], given["tau_max"]
        eps_margin, svd_tol, reg = given["eps_margin"], given["svd_tol"], given["reg"]
        consistency, actuated_dofs = given["consistency"], given["actuated_dofs"]

        def scalar(name: str, value: object, want: str, ok: Callable[[float], bool]) -> float:
            try:
                v = float(value)  # type: ignore[arg-type]
            except (TypeError, ValueError) as err:
                raise _bad(owner, name, value, want) from err
            if np.isnan(v) or not ok(v):
                raise _bad(owner, name, value, want)
            return v

        mu_ = scalar("mu", mu, "a finite number >= 0", lambda v: 0.0 <= v < np.inf)
        fmin = scalar("f_n_min", f_n_min, "a finite number >= 0 [N]", lambda v: 0.0 <= v < np.inf)
        eps = scalar("eps_margin", eps_margin, "a number >= 0 [N]", lambda v: v >= 0.0)
        tol = scalar("svd_tol", svd_tol, "a finite number > 0", lambda v: 0.0 < v < np.inf)
        reg_ = scalar("reg", reg, "a finite number > 0", lambda v: 0.0 < v < np.inf)
        tau = _checked_tau_max(owner, tau_max)
        dofs = None if actuated_dofs is None else _checked_dofs(owner, actuated_dofs)
        return cls(mu_, fmin, tau, eps, tol, reg_, bool(consistency), dofs)

    def dofs_and_limits(
        self, n_v: int, owner: str = "AllocationParams"
    ) -> tuple[IntArray, FloatArray]:
        """Actuated joint indices (n_a,) and their torque limits (n_a,) [N*m] for ``n_v`` joints
        (read-only arrays, kept for the next call with the same ``n_v``).

        A mask or limit array whose length is not ``n_v`` raises :class:`ConfigError`.
        """
        kept = self.__dict__.get("_limits")
        if kept is not None and kept[0] == n_v:
            return kept[1], kept[2]
        if self.actuated_dofs is None:
            dofs = np.arange(n_v, dtype=np.intp)
        else:
            dofs = self.actuated_dofs
            if dofs.size and dofs[-1] >= n_v:
                raise ConfigError(
                    f"{owner}: actuated_dofs holds joint index {int(dofs[-1])} but J_world has "
                    f"only n_v={n_v} columns; pass indices in [0, {n_v})"
                )
        if np.ndim(self.tau_max) == 0:
            limits = np.full(dofs.size, float(self.tau_max))
        else:
            tmax = np.asarray(self.tau_max)
            if tmax.shape != (n_v,):
                raise ConfigError(
                    f"{owner}: tau_max has shape {tmax.shape} but J_world has n_v={n_v} joints; "
                    f"pass a scalar or an array of shape ({n_v},)"
                )
            limits = tmax[dofs]
        dofs, limits = dofs.copy(), np.array(limits, dtype=np.float64)
        dofs.setflags(write=False)
        limits.setflags(write=False)
        object.__setattr__(self, "_limits", (n_v, dofs, limits))  # frozen: a memo, not a field
        return dofs, limits

    @functools.cached_property
    def edges(self) -> FloatArray:
        """(3, 4) pyramid edges of :func:`friction_edges` at :attr:`mu` (read-only)."""
        E = friction_edges(self.mu)
        E.setflags(write=False)
        return E


@dataclass(frozen=True)
class AllocationQP:
    """The allocation QP of one cycle in structured form (pyramid-edge, wrench-split).

    Variables ``x = [lambda (4N); w (6)]``, ``lambda`` ordered contact-major (``4 i + k``).
    """

    params: AllocationParams
    """Constants the problem was built with."""
    n_v: int
    """Number of joint velocities (columns of ``J_world``)."""
    wRc: FloatArray  # noqa: N815 (pose notation: rotation of contact frames in world)
    """(N, 3, 3) contact frames, columns ``[e_n (into the object), t_1, t_2]`` in world axes."""
    r_world: FloatArray
    """(N, 3) contact points relative to the COM, world axes [m]."""
    W: FloatArray
    """(N, 3, 4) pyramid edges of each contact in world axes: ``f_world_i = W_i lambda_i``."""
    G_lam: FloatArray
    """(6, 4N) grasp matrix on the edge weights: ``w = G_lam lambda``."""
    act_idx: IntArray
    """(N_act,) indices of the contacts on actuated links."""
    dofs: IntArray
    """(n_a,) indices of the commanded joints in ``[0, n_v)``."""
    J_act: FloatArray
    """(3 N_act, n_a) stacked point Jacobians of the actuated contacts, world axes, commanded
    joints only; acts on world-axis forces of the hand on the object."""
    tau_max: FloatArray
    """(n_a,) torque limits of the commanded joints [N*m]."""
    torque_rows: IntArray
    """(n_t,) positions in ``dofs`` of the joints with torque rows (moved by some actuated
    contact and with a finite limit)."""
    T_lam: FloatArray
    """(n_t, 4N) torque rows on ``lambda``: ``tau[dofs[torque_rows]] = T_lam @ lambda`` [N*m]."""
    null: ActuationNullSpace | None
    """Basis of ``Null(J_act^T)``; None when consistency is off or no contact is actuated."""
    w_ext: FloatArray = field(default_factory=lambda: np.zeros(N_WRENCH))
    """(6,) known external wrench on the object about its COM, world axes [N, N*m] (e.g. its
    weight); the objective is the net wrench ``||G f + w_ext||^2`` (zero: the paper's)."""
    tau_bias: FloatArray | None = None
    """(n_a,) torque the commanded joints carry besides the contact forces [N*m] (the hand
    links' own weight, say): the limits then bind ``tau_bias + J_act^T f_act``; None: zero (the
    paper's)."""

    @functools.cached_property
    def G(self) -> FloatArray:  # noqa: N802 - the paper's symbol
        """(6, 3N) grasp matrix on local forces: wrench [N; N*m] about the COM, world axes."""
        return wrench_map(self.r_world, self.wRc)

    @property
    def n_contacts(self) -> int:
        return int(self.wRc.shape[0])

    @property
    def n_lambda(self) -> int:
        """Number of edge weights, 4N."""
        return N_EDGES * self.n_contacts

    @property
    def n_x(self) -> int:
        """Number of variables, 4N + 6."""
        return self.n_lambda + N_WRENCH

    @property
    def n_null(self) -> int:
        """Number of actuation-consistency rows (0 when off)."""
        return 0 if self.null is None else self.null.dim

    def f_local(self, lam: FloatArray) -> FloatArray:
        """(N, 3) local forces ``[f_n, f_t1, f_t2]`` [N] from (4N,) edge weights."""
        return cast(FloatArray, lam.reshape(-1, N_EDGES) @ self.params.edges.T)

    def f_world(self, lam: FloatArray) -> FloatArray:
        """(N, 3) world-axis forces of the hand on the object [N] from (4N,) edge weights."""
        forces = edge_forces(self.W, np.ascontiguousarray(lam), np.arange(self.n_contacts))
        return cast(FloatArray, forces)

    def f_act(self, lam: FloatArray) -> FloatArray:
        """(3 N_act,) stacked world-axis forces of the actuated contacts [N]."""
        return cast(
            FloatArray, edge_forces(self.W, np.ascontiguousarray(lam), self.act_idx).ravel()
        )

    def tau(self, lam: FloatArray) -> FloatArray:
        """(n_v,) joint torques ``J_act^T f_act`` [N*m]; zero on joints not commanded."""
        tau = np.zeros(self.n_v)
        tau[self.dofs] = self.J_act.T @ self.f_act(lam)
        return tau

    @functools.cached_property
    def torque_limits(self) -> FloatArray:
        """(n_t,) the limits of the torque rows' joints [N*m] (``tau_max[torque_rows]``; computed
        once, shared: read it, do not write it)."""
        return cast(FloatArray, self.tau_max[self.torque_rows])

    def torque_totals(self, values: FloatArray) -> FloatArray:
        """(n_t,) joint torques the torque rows limit [N*m]: their ``values`` (``T_lam @
        lambda``) plus :attr:`tau_bias`."""
        if self.tau_bias is None:
            return values
        return values + self.tau_bias[self.torque_rows]

    def torque_bounds(self) -> tuple[FloatArray, FloatArray]:
        """(n_t,) lower and upper bounds of the torque rows ``T_lam @ lambda`` [N*m] (new
        arrays)."""
        lim = self.torque_limits
        if self.tau_bias is None:
            return -lim, lim.copy()
        bias = self.tau_bias[self.torque_rows]
        return -lim - bias, lim - bias

    def null_values(self, lam: FloatArray) -> FloatArray:
        """(n_null,) consistency values ``N_u^T f_act`` [N]."""
        if self.null is None:
            return np.zeros(0)
        return self.null.project(self.f_act(lam))

    def null_rows(self, idx: IntArray) -> FloatArray:
        """(len(idx), 4N) consistency rows ``(N_u^T f_act)[idx]`` as functions of ``lambda``
        (none for an empty ``idx``, also in a problem without consistency rows)."""
        if idx.size == 0:
            return np.zeros((0, self.n_lambda))
        assert self.null is not None
        # C order whatever LAPACK left, so that the kernel sees one layout (each layout is a
        # kernel of its own, loaded on first use: milliseconds, in a control cycle).
        Nc = np.ascontiguousarray(self.null.columns(idx)).reshape(-1, 3, len(idx))  # (N_act, 3, k)
        return cast(FloatArray, consistency_rows(Nc, self.W, self.act_idx))

    def violation(self, x: FloatArray) -> float:
        """Largest violation of any constraint at ``x`` (4N + 6,) or ``lambda`` (4N,) [N, N*m].

        The equality ``w = G_lam lambda`` is not counted: ``w`` is recomputed from ``lambda``.
        """
        lam = x[: self.n_lambda]
        v = [0.0, float(-lam.min(initial=0.0)), self.params.f_n_min - float(lam.sum())]
        if self.torque_rows.size:
            t = self.torque_totals(self.T_lam @ lam)
            v.append(float((np.abs(t) - self.torque_limits).max()))
        if self.n_null:
            v.append(float(np.abs(self.null_values(lam)).max() - self.params.eps_margin))
        out = max(v)
        return out if np.isfinite(out) else np.inf


def build_allocation_qp(
    contacts: ContactSet,
    J_world: FloatArray,
    p_com_world: FloatArray,
    params: AllocationParams,
    owner: str = "build_allocation_qp",
    w_ext: FloatArray | None = None,
    tau_bias: FloatArray | None = None,
) -> AllocationQP:
    """The allocation QP of the current contacts.

    Args:
        contacts: The N contacts of this cycle (N >= 1).
        J_world: (N, 3, n_v) point Jacobians at the contacts: linear velocity of each hand
            contact point in world axes per joint velocity [m/rad or -].
        p_com_world: (3,) object centre of mass in the world [m].
        params: QP constants.
        owner: Name used in error messages.
        w_ext: (6,) known external wrench on the object about its COM, world axes [N, N*m];
            None: zero (the paper's quasi-static balance).
        tau_bias: (n_v,) torque the joints command besides the contact forces [N*m] (their
            links' weight, say), kept within the limits together with them; None: zero.

    Raises:
        ConfigError: ``J_world``, ``p_com_world``, ``tau_max`` or ``actuated_dofs`` do not match
            the contacts or the number of joints.
    """
    n = len(contacts)
    J_world = checked_jacobians(J_world, n, owner)
    p_com_world = np.asarray(p_com_world, dtype=np.float64)
    if p_com_world.shape != (3,):
        raise ConfigError(f"{owner}: p_com_world has shape {p_com_world.shape}, expected (3,)")
    n_v = J_world.shape[2]
    dofs, tau_max = params.dofs_and_limits(n_v, owner)
    wRc, r_world, W, G_lam, act_idx, J_act, moved, torque_rows, T_lam = structured_terms(
        np.ascontiguousarray(contacts.n_world, dtype=np.float64),
        np.ascontiguousarray(contacts.p_world, dtype=np.float64),
        p_com_world,
        params.edges,
        np.ascontiguousarray(J_world),
        contacts.actuated,
        dofs,
        tau_max,
    )
    null = None
    if params.consistency and act_idx.size:
        null = ActuationNullSpace(J_act, params.svd_tol, moved)
    return AllocationQP(
        params=params,
        n_v=n_v,
        wRc=wRc,
        r_world=r_world,
        W=W,
        G_lam=G_lam,
        act_idx=act_idx,
        dofs=dofs,
        J_act=J_act,
        tau_max=tau_max,
        torque_rows=torque_rows,
        T_lam=T_lam,
        null=null,
        **({} if w_ext is None else {"w_ext": _wrench(w_ext, owner)}),
        tau_bias=None if tau_bias is None else _bias(tau_bias, n_v, owner)[dofs],
    )


def _wrench(w_ext: npt.ArrayLike, owner: str) -> FloatArray:
    w = np.asarray(w_ext, dtype=np.float64)
    if w.shape != (N_WRENCH,) or not np.isfinite(w).all():
        raise ConfigError(
            f"{owner}: external wrench must be 6 finite numbers [N, N*m], got {w_ext!r}"
        )
    return w


def _bias(tau_bias: npt.ArrayLike, n_v: int, owner: str) -> FloatArray:
    b = np.asarray(tau_bias, dtype=np.float64)
    if b.shape != (n_v,) or not np.isfinite(b).all():
        raise ConfigError(
            f"{owner}: tau_bias must be {n_v} finite joint torques [N*m] (one per column of "
            f"J_world), got shape {b.shape}"
        )
    return b
