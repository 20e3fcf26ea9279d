"""Eigen solvers (SLEPc, SciPy), certification, rigid-mode handling and mode labels."""
