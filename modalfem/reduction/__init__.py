"""Reduced bases: Rayleigh-Ritz (affine, affine + quadratic), coarse-to-fine embedding, boundary-only restriction."""
