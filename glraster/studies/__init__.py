"""Measurement programs: benchmark, fill limit, stress sweeps, distortion figure, pyrender
cross-check."""
