"""The cloth collision pipeline of Bridson, Fedkiw and Anderson (2002), each stage switchable.

One call of :meth:`CollisionPipeline.resolve` takes collision-free start positions ``x0`` and candidate
velocities ``v`` for a step ``dt`` and returns new velocities ``v_new`` such that the straight-line
trajectory ``x0 + s * dt * v_new`` (s in [0, 1]) has no crossing (self and obstacles):

(a) repulsion: point-triangle and edge-edge pairs closer than the thickness ``h`` at ``x0`` get an
    inelastic impulse plus a soft repulsion (the cloth thickness), with Coulomb friction;
(b) continuous collision detection (CCD, conservative, see :mod:`modalfem.collision.ccd`) of the
    trajectories, inelastic impulses at the first time of contact, ``ccd_passes`` passes;
(c) rigid impact zones (Provot): colliding vertices are merged into zones that move rigidly with
    their linear and angular momentum (or with their pinned vertices / obstacle), until collision-free.

Stage (d) of the paper, smoothing the velocity change by an implicit damping solve, belongs to the
cloth solver (it owns the damping matrix): the change applied here is ``v_new - v`` and the vertices
touched are ``stats.touched``.

Obstacles (:mod:`modalfem.collision.obstacles`) are kinematic: planes and spheres act on cloth
vertices, triangle meshes (static or moving) join the point-triangle and edge-edge tests with
infinite-mass vertices. Pinned cloth vertices have ``masses = np.inf``: impulses never move them.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from modalfem.collision.repulsion import SWEEPS
from modalfem.errors import InputError, SceneError, SimulationError

__all__ = ["CollisionConfig", "CollisionPipeline", "CollisionStats"]


@dataclass(frozen=True)
class CollisionConfig:
    """Switches and parameters of the collision pipeline.

    Attributes:
        thickness: cloth thickness ``h`` [m]: repulsion acts on pairs closer than this.
        friction: Coulomb friction coefficient [-] of repulsion contacts.
        repulsion: run stage (a).
        ccd: run stage (b).
        impact_zones: run stage (c), the fail-safe (off: collisions may remain, see
            ``CollisionStats.unresolved``).
        self_collision: test the cloth against itself (off: obstacles only).
        culling: normal-cone (and contour) culling of the self-collision tests over the BVH in the
            proximity search of stage (a) (positions at the step start: the culled pairs stay valid for the
            whole step).
        swept_culling: the same culling in the swept searches of stages (b) and (c) too. Off by default: a
            pair culled there is only known collision-free for the very trajectories its normal cones were
            computed for, so every later velocity change beyond ``min_separation`` (CCD impulses, impact
            zones, the re-check after smoothing) has to search its vertices again, while unculled
            candidates stay valid until a trajectory leaves its box (grown by ``SLACK`` times the
            thickness). Measured on replayed 64x64 steps (same states, fastest of 3): pile steps 40-80 289 ->
            235 ms/step, pile steps 0-40 99 -> 91, drape 67.5 -> 56 with it off.
        repulsion_iterations: sweeps of stage (a)'s impulses over the close pairs (>= 1), pair by pair
            (:func:`modalfem.collision.repulsion.sequential_pair_impulses`); they stop early once every
            pair is at its target. Replayed 64x64 pile steps 40-80 (fastest of 3): 245 ms/step with the
            earlier 20 averaged (Jacobi) passes, 231 with 10 sweeps, which also leave 10x fewer pairs
            still approaching (a largest remaining approach of 0.06 m/s instead of 0.20 m/s at step 44).
        ccd_passes: passes of stage (b).
        min_separation: CCD tolerance ``eta`` [m]: trajectories coming closer than this count as
            colliding (default ``1e-3 * thickness``).
        max_zone_iterations: iterations of stage (c) before giving up (a warning, and
            ``CollisionStats.unresolved`` > 0).
        measure_culling: also count the pair tests without culling (one more BVH traversal per
            step) for ``CollisionStats.pair_tests_unculled``.
    """

    thickness: float
    friction: float = 0.3
    repulsion: bool = True
    ccd: bool = True
    impact_zones: bool = True
    self_collision: bool = True
    culling: bool = True
    swept_culling: bool = False
    repulsion_iterations: int = SWEEPS
    ccd_passes: int = 3
    min_separation: float | None = None
    max_zone_iterations: int = 200
    measure_culling: bool = False

    def __post_init__(self) -> None:
        if not (np.isfinite(self.thickness) and self.thickness > 0):
            raise InputError(f"collision thickness must be a positive number of metres, got {self.thickness}")
        if not (np.isfinite(self.friction) and self.friction >= 0):
            raise InputError(f"friction coefficient must be >= 0, got {self.friction}")
        if int(self.repulsion_iterations) < 1:
            raise InputError(f"repulsion_iterations must be >= 1, got {self.repulsion_iterations}")
        if int(self.ccd_passes) < 0:
            raise InputError(f"ccd_passes must be >= 0, got {self.ccd_passes}")
        if self.min_separation is not None and not (self.min_separation > 0):
            raise InputError(f"min_separation must be > 0 [m], got {self.min_separation}")

    @property
    def eta(self) -> float:
        """CCD minimum separation [m]."""
        return float(self.min_separation) if self.min_separation is not None else 1e-3 * self.thickness


@dataclass
class CollisionStats:
    """What one :meth:`CollisionPipeline.resolve` did.

    Attributes:
        seconds: wall time per stage [s]: keys ``broad_phase``, ``repulsion``, ``ccd``,
            ``impact_zones``, ``total``.
        pair_tests_unculled: triangle-pair tests the BVH traversals would do without normal-cone
            culling (None unless ``CollisionConfig.measure_culling``).
        pair_tests: triangle-pair (leaf) tests actually done (after culling), summed over the proximity
            traversal (boxes at ``x0`` grown by h/2) and the first swept traversal (trajectory boxes);
            0 when the call re-used the traversals of an earlier call with the same ``x0``, ``dt`` and
            ``t`` (the re-check after smoothing); the searches for dirty vertices (and the fresh search
            of a later call whose vertices are mostly dirty) are not counted.
        candidates_vf: point-triangle candidate pairs of those traversals.
        candidates_ee: edge-edge candidate pairs of those traversals.
        proximities: repulsion pairs closer than the thickness (stage a).
        ccd_hits: colliding primitive pairs found in each CCD pass (stage b).
        zone_iterations: iterations of stage (c).
        zone_sizes: vertex counts of the final impact zones (cloth vertices only).
        unresolved: colliding pairs left when the pipeline stopped (0 when stage (c) succeeded).
        touched: (n,) bool, vertices whose velocity was changed.
    """

    seconds: dict = field(default_factory=dict)
    pair_tests_unculled: int | None = None
    pair_tests: int = 0
    candidates_vf: int = 0
    candidates_ee: int = 0
    proximities: int = 0
    ccd_hits: list = field(default_factory=list)
    zone_iterations: int = 0
    zone_sizes: list = field(default_factory=list)
    unresolved: int = 0
    touched: np.ndarray | None = None

    @property
    def culled_fraction(self) -> float:
        """Fraction [-] of triangle-pair tests removed by culling."""
        if not self.pair_tests_unculled:
            return 0.0
        return 1.0 - self.pair_tests / self.pair_tests_unculled


class CollisionPipeline:
    """Stages (a)-(c) of the Bridson-Fedkiw-Anderson pipeline for one cloth mesh and its obstacles.

    Args:
        triangles: (m, 3) int cloth triangles (vertex indices into the ``x0`` given to ``resolve``).
        config: switches and parameters.
        obstacles: kinematic obstacles (``Plane``, ``Sphere``, ``TriangleMeshObstacle``).
        n_vertices: number of cloth vertices (default: largest index in ``triangles`` + 1).
        reference_positions: (n, 3) positions [m] that group the triangles of the BVH, best the rest
            (unfolded) shape so that BVH nodes are compact surface patches that normal cones can cull
            (default: ``x0`` of the first ``resolve``).

    Raises:
        InputError: malformed triangles or an unknown obstacle type.
    """

    def __init__(
        self,
        triangles: np.ndarray,
        *,
        config: CollisionConfig,
        obstacles: Sequence = (),
        n_vertices: int | None = None,
        reference_positions: np.ndarray | None = None,
    ) -> None:
        from modalfem.collision import _system

        self.config = config
        self.triangles = _system.check_triangles(triangles)
        self.obstacles = tuple(obstacles)
        self._system = _system.System(self.triangles, self.obstacles, n_vertices)
        if reference_positions is not None:
            ref = np.asarray(reference_positions, dtype=float)
            if ref.shape != (self._system.n_cloth, 3) or not np.isfinite(ref).all():
                raise InputError(f"reference_positions must be finite ({self._system.n_cloth}, 3), got {ref.shape}")
            self._system.build_cloth_bvh(ref)

    def resolve(
        self, x0: np.ndarray, v: np.ndarray, masses: np.ndarray, dt: float, *, t: float = 0.0
    ) -> tuple[np.ndarray, CollisionStats]:
        """New velocities whose straight-line step from ``x0`` is collision-free.

        Args:
            x0: (n, 3) start positions [m], collision-free (see :meth:`check_initial`).
            v: (n, 3) candidate velocities [m/s] (after the cloth's internal forces).
            masses: (n,) vertex masses [kg]; ``np.inf`` pins a vertex (its velocity is kept).
            dt: step [s], > 0.
            t: time [s] at ``x0`` (moving obstacles are evaluated at ``t`` and ``t + dt``).

        Returns:
            ``(v_new, stats)``: (n, 3) velocities [m/s] such that ``x0 + s * dt * v_new`` has no crossing
            for s in [0, 1] (when ``stats.unresolved == 0``), and the :class:`CollisionStats`.

        Raises:
            InputError: shapes do not match the mesh.
            SimulationError: dt <= 0 or non-finite positions/velocities, or non-positive masses.
        """
        from modalfem.collision import _stages

        x0, v, masses, dt = self._check_state(x0, v, masses, dt)
        return _stages.resolve(self._system, self.config, x0, v, masses, dt, float(t))

    def check_initial(self, x0: np.ndarray, *, t: float = 0.0, strict: bool = False) -> int:
        """Count intersecting triangle pairs at ``x0`` (self and obstacles), with the independent test.

        Args:
            x0: (n, 3) positions [m].
            t: time [s] at which moving obstacles are evaluated.
            strict: raise instead of warning.

        Returns:
            Number of intersecting triangle pairs (plus cloth vertices inside a sphere or below a plane).

        Raises:
            SceneError: when ``strict`` and the cloth starts in intersection.
        """
        from modalfem.collision import _system

        x0 = np.asarray(x0, dtype=float)
        count = _system.count_intersections(self._system, x0, float(t), self.config.self_collision)
        if count:
            msg = f"cloth starts in intersection: {count} intersecting pairs (self and obstacles)"
            if strict:
                raise SceneError(msg)
            warnings.warn(msg, stacklevel=2)
        return count

    def _check_state(self, x0, v, masses, dt):
        n = self._system.n_cloth
        x0 = np.asarray(x0, dtype=float)
        v = np.asarray(v, dtype=float)
        masses = np.asarray(masses, dtype=float)
        if x0.shape != (n, 3) or v.shape != (n, 3) or masses.shape != (n,):
            raise InputError(
                f"collision state shapes must be x0 ({n}, 3), v ({n}, 3), masses ({n},); "
                f"got {x0.shape}, {v.shape}, {masses.shape}"
            )
        if not (np.isfinite(dt) and dt > 0):
            raise SimulationError(f"time step must be > 0 s, got {dt}")
        if not (np.isfinite(x0).all() and np.isfinite(v).all()):
            raise SimulationError("non-finite positions or velocities given to the collision pipeline")
        if not (masses > 0).all() or np.isnan(masses).any():
            raise SimulationError("vertex masses must be > 0 kg (np.inf pins a vertex)")
        return x0, v, masses, float(dt)
