"""Differentiable rasterization (Laine et al. 2020, "Modular Primitives for
High-Performance Differentiable Rendering"), framework-free: NumPy arrays in and out.

Each op has a ``forward`` returning its outputs and what its backward needs, a
``backward(saved, grads) -> grads of the inputs``, and a float64 reference of both
(:mod:`glraster.diff.reference`). Layouts follow nvdiffrast's documented API so that the
adapters (:mod:`glraster.torch`) stay thin; see docs/differentiable.md.
"""
