"""Collision: broad phase (BVH, normal cones), distances, continuous collision detection, impact zones.

The cloth collision pipeline of Bridson, Fedkiw and Anderson (2002), each stage switchable:

- :mod:`modalfem.collision.pipeline`: ``CollisionConfig``, ``CollisionPipeline`` (``resolve`` returns
  collision-free velocities for one step and ``CollisionStats``), ``check_initial``;
- :mod:`modalfem.collision.obstacles`: ``Plane``, ``Sphere``, ``TriangleMeshObstacle``;
- :mod:`modalfem.collision.ccd`: conservative vertex-face / edge-edge CCD over batches;
- :mod:`modalfem.collision.distance`: closest points and distance lower bounds;
- :mod:`modalfem.collision.bvh`: ``BroadPhaseBVH`` (swept boxes, normal-cone culling);
- :mod:`modalfem.collision.repulsion`, :mod:`modalfem.collision.zones`: stages (a) and (c);
- :mod:`modalfem.collision.tritri`: ``intersecting_pairs``, an independent triangle-triangle test.

Import from the submodules (``from modalfem.collision.pipeline import CollisionPipeline``); this
package imports nothing on its own so that ``import modalfem`` stays light. Runtime code: NumPy, and
numba kernels (``_bvh_kernels``, ``_contour_kernels``, ``_pair_kernels``, ``_ccd_kernels``,
``_distance_kernels``: loops over nodes, pairs and queries, compiled on first call and cached next to the
modules).
"""
