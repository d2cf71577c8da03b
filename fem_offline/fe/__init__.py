"""The finite-element problem: materials, boundary conditions, the guide and its contact, gravity, the
neo-Hookean and Taylor-Hood elements, assembly, linear solvers, Newton, load stepping and the linear model."""
