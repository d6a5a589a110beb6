"""QP solver adapters, one per module, and their registry (as qpsolvers keeps its own).

Solvers are named by a string. ``"dual_active_set"`` is the project's own solver of the
structured allocation QP (:mod:`~wholehand.allocation.solvers.dual_active_set`), chosen through
the QP allocator's :class:`~wholehand.allocation.options.SolveOptions` rather than built here as
a dense adapter. ``"daqp"``, ``"osqp"`` and ``"piqp"`` are driven through their own
Python APIs: a persistent DAQP model per problem shape, OSQP without the wrapper's conversions,
PIQP's sparse KKT solver (the qpsolvers wrappers add per-cycle conversions; ``wholehand bench
allocate`` compares them). Any other name in ``qpsolvers.available_solvers``, and
``"qpsolvers:<name>"`` for any of them, goes through :func:`qpsolvers.solve_problem`.
:func:`available_solvers` lists what is installed; an unknown name raises :class:`ConfigError`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from wholehand.allocation.solvers.base import BIG, DenseQP, QPResult, QPSolver
from wholehand.allocation.solvers.daqp_solver import DaqpSolver
from wholehand.allocation.solvers.osqp_solver import OsqpSolver
from wholehand.allocation.solvers.piqp_solver import PiqpSolver
from wholehand.allocation.solvers.qpsolvers_solver import QpsolversSolver
from wholehand.errors import ConfigError

NATIVE_SOLVERS: dict[str, type[QPSolver]] = {}
"""Solvers driven through their own API, filled by guarded imports."""

for _cls, _module in ((DaqpSolver, "daqp"), (OsqpSolver, "osqp"), (PiqpSolver, "piqp")):
    try:
        __import__(_module)
    except ImportError:  # pragma: no cover - depends on the environment
        continue
    NATIVE_SOLVERS[_cls.name] = _cls

DEFAULT_SOLVER: str = "dual_active_set"
"""The allocators' solver: the structured one, fastest where it matters, near a loss
(``wholehand bench cycle --worst``; docs/results.md)."""

STRUCTURED_SOLVERS: tuple[str, ...] = ("dual_active_set",)
"""Solvers of the structured allocation QP, which the QP allocator drives itself."""


def _qpsolvers_available() -> list[str]:
    try:
        import qpsolvers
    except ImportError:  # pragma: no cover
        return []
    return list(qpsolvers.available_solvers)


def available_solvers() -> list[str]:
    """Every solver name :func:`make_solver` accepts in this environment."""
    generic = _qpsolvers_available()
    plain = [s for s in generic if s not in NATIVE_SOLVERS]
    return [*STRUCTURED_SOLVERS, *NATIVE_SOLVERS, *plain, *(f"qpsolvers:{s}" for s in generic)]


def make_solver(
    name: str, settings: Mapping[str, Any] | None = None, owner: str = "make_solver"
) -> QPSolver:
    """The adapter for solver ``name`` with ``settings`` on top of its defaults.

    User ``settings`` are tried once on a tiny problem, so that a bad one fails here.

    Raises:
        ConfigError: ``name`` is not an installed solver (the message lists the installed
            ones), or the solver rejects ``settings``.
    """
    generic = _qpsolvers_available()
    solver: QPSolver | None = None
    if name in STRUCTURED_SOLVERS:
        raise ConfigError(
            f"{owner}: solver {name!r} solves the structured allocation QP and is chosen in the "
            f"QP allocator's options (SolveOptions(solver={name!r})), not built as a dense QP "
            f"adapter; dense solvers: {', '.join(available_solvers()[len(STRUCTURED_SOLVERS) :])}"
        )
    if isinstance(name, str):
        base = name.removeprefix("qpsolvers:")
        if name in NATIVE_SOLVERS:
            try:
                solver = NATIVE_SOLVERS[name](settings)
            except ConfigError as err:  # an adapter that checks its settings itself
                raise ConfigError(f"{owner}: {err}") from None
        elif base in generic:
            solver = QpsolversSolver(base, settings)
    if solver is not None:
        if settings:
            solver.probe(owner)
        return solver
    raise ConfigError(
        f"{owner}: parameter solver={name!r} is not an installed QP solver; installed: "
        f"{', '.join(available_solvers()) or 'none'}. Install another with e.g. "
        f"`pip install qpsolvers[clarabel]` or `pip install proxsuite`."
    )


__all__ = [
    "BIG",
    "DEFAULT_SOLVER",
    "NATIVE_SOLVERS",
    "DaqpSolver",
    "DenseQP",
    "OsqpSolver",
    "PiqpSolver",
    "QPResult",
    "QPSolver",
    "QpsolversSolver",
    "STRUCTURED_SOLVERS",
    "available_solvers",
    "make_solver",
]
