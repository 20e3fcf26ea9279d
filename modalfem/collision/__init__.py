"""Collision: broad phase (BVH, normal cones), distances, continuous collision detection, impact zones."""
