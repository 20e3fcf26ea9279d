"""Cloth: membrane and bending energies, wind, implicit steps, and the collision pipeline driver.

Modules: ``mesh`` (``ClothMesh``, ``grid``, ``read_cloth``), ``energies`` (``Membrane``, ``Bending``),
``model`` (``ClothMaterial``, ``ClothModel``, ``Handle``), ``wind`` (``Wind``), ``solver``
(``ImplicitEuler``), ``scene`` (``ClothScene``: gravity, wind, collisions, smoothing on request),
``scenes`` (the issue-6 test scenes), ``render`` (pictures through ``modalfem.output.animation``).
"""
