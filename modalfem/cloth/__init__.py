"""Cloth: membrane and bending energies, wind, implicit steps, and the collision pipeline driver."""
