"""Large-deformation tetrahedral bodies: corotational / invertible FEM, volume springs, implicit steps."""
