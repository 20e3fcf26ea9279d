"""Dirichlet constraints: which displacement DOFs are held at zero.

A constraint names *where* (a boundary tag of the mesh, or a predicate on node coordinates) and
*which components* (any subset of ``"xyz"``). ``fixed_mask`` turns any accepted spelling into a
boolean mask over the DOFs in the canonical node-major order of ``modalfem.mesh.core``::

    fixed_mask(mesh, 2, "x0")                                 # clamp the x0 face
    fixed_mask(mesh, 2, [Fix("z0", components="z"), "x1"])   # roller on z0, clamp x1
    fixed_mask(mesh, 2, lambda p: p[:, 0] < 1e-9)             # predicate on node coordinates [m]
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Union

import numpy as np

from modalfem.errors import ConstraintError

__all__ = ["Fix", "FixedSpec", "fixed_mask"]

Predicate = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class Fix:
    """Hold some displacement components at zero on part of the mesh.

    Args:
        where: a boundary tag name of the mesh (its triangles, with P2 edge midpoints), or a predicate
            ``p -> mask`` taking node coordinates ``p`` (n, 3) [m] and returning a boolean mask (n,).
        components: the held components, any non-empty subset of ``"xyz"`` (``"z"`` makes a roller).

    Raises:
        ConstraintError: ``where`` is neither a string nor callable, or ``components`` is not a
            non-empty subset of ``"xyz"``.
    """

    where: Union[str, Predicate]
    components: str = field(default="xyz", kw_only=True)

    def __post_init__(self) -> None:
        if not (isinstance(self.where, str) or callable(self.where)):
            raise ConstraintError(
                f"Fix(where=...) must be a tag name or a predicate p -> mask, got {type(self.where).__name__}"
            )
        comps = self.components
        if (
            not isinstance(comps, str)
            or not comps
            or set(comps) - set("xyz")
            or len(set(comps)) != len(comps)
        ):
            raise ConstraintError(f"Fix components must be a non-empty subset of 'xyz', got {comps!r}")
        object.__setattr__(self, "components", "".join(sorted(comps)))

    def describe(self) -> str:
        """Short text such as ``"x0"`` or ``"z0[z]"`` or ``"<predicate>[xyz]"``."""
        where = self.where if isinstance(self.where, str) else f"<{getattr(self.where, '__name__', 'predicate')}>"
        return where if self.components == "xyz" else f"{where}[{self.components}]"


FixedSpec = Union[None, str, Predicate, Fix, Iterable[Union[str, Predicate, Fix]]]


def _as_fixes(fixed: FixedSpec) -> list[Fix]:
    if fixed is None:
        return []
    if isinstance(fixed, (str, Fix)) or callable(fixed):
        items = [fixed]
    elif isinstance(fixed, Iterable):
        items = list(fixed)
    else:
        raise ConstraintError(
            f"fixed must be None, a tag name, a predicate, a Fix or a list of those, got {type(fixed).__name__}"
        )
    out = []
    for it in items:
        if isinstance(it, Fix):
            out.append(it)
        elif isinstance(it, str) or callable(it):
            out.append(Fix(it))
        else:
            raise ConstraintError(
                f"fixed entries must be tag names, predicates or Fix objects, got {type(it).__name__}"
            )
    return out


def _predicate_nodes(fix: Fix, points: np.ndarray) -> np.ndarray:
    name = fix.describe()
    try:
        raw = fix.where(points.copy())
    except ConstraintError:
        raise
    except Exception as exc:  # the user's code failed: one clear line, not their traceback
        raise ConstraintError(f"fixed={name} predicate raised {type(exc).__name__}: {exc}") from None
    try:
        mask = np.asarray(raw)
    except Exception:
        raise ConstraintError(f"fixed={name} predicate returned {type(raw).__name__}, not an array") from None
    n = len(points)
    if mask.shape != (n,):
        raise ConstraintError(
            f"fixed={name} predicate must return a boolean mask of shape ({n},) for points of shape ({n}, 3), "
            f"got shape {mask.shape} dtype {mask.dtype}"
        )
    if mask.dtype != np.bool_:
        ok = np.issubdtype(mask.dtype, np.integer) and np.all((mask == 0) | (mask == 1))
        if not ok:
            raise ConstraintError(
                f"fixed={name} predicate must return a boolean mask, got dtype {mask.dtype} "
                "(compare coordinates, e.g. p[:, 0] < 1e-9)"
            )
        mask = mask.astype(bool)
    return np.flatnonzero(mask)


def fixed_mask(mesh, degree: int, fixed: FixedSpec) -> np.ndarray:
    """Boolean mask of the fixed DOFs (3 * N_nodes,) in the canonical node-major order.

    Args:
        mesh: the ``Mesh``.
        degree: Lagrange degree, 1 or 2 (P2 adds the edge-midpoint nodes).
        fixed: None (free body), a tag name, a predicate ``p (n, 3) [m] -> bool mask (n,)``, a ``Fix``,
            or a list/tuple of those (their union).

    Returns:
        mask (3 * mesh.node_count(degree),) of dtype bool, True on held DOFs.

    Raises:
        ConstraintError: unknown tag (known tags listed), predicate with a result of the wrong shape or
            dtype or that raised, a constraint that selects no nodes, a malformed ``fixed`` value.
    """
    from modalfem.errors import InputError

    if degree not in (1, 2):
        raise InputError(f"degree must be 1 or 2, got {degree!r}")
    n_nodes = mesh.node_count(degree)
    mask = np.zeros((n_nodes, 3), dtype=bool)
    points = None
    for fix in _as_fixes(fixed):
        if isinstance(fix.where, str):
            facets = mesh.tag_facets(fix.where)  # ConstraintError listing the known tags
            nodes = mesh.facet_nodes(facets, degree) if len(facets) else np.empty(0, dtype=np.int64)
        else:
            if points is None:
                points = mesh.dof_points(degree)
            nodes = _predicate_nodes(fix, points)
        if len(nodes) == 0:
            raise ConstraintError(f"fixed={fix.describe()} selects no nodes")
        cols = ["xyz".index(c) for c in fix.components]
        mask[np.ix_(nodes, cols)] = True
    return mask.ravel()
