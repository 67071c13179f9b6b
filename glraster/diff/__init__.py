"""Differentiable rasterization (Laine et al. 2020, "Modular Primitives for
High-Performance Differentiable Rendering"), framework-free: NumPy arrays in and out.

Each op (:mod:`glraster.diff.ops`) has two cores with one signature,
``forward(*inputs, **params) -> (outputs, saved)`` and
``backward(saved, *grads, needs=None) -> grads of the inputs`` (:mod:`glraster.diff.op`):
the GPU core (float32, e.g. :mod:`glraster.diff.rasterize`) and its float64 reference
(e.g. :mod:`glraster.diff.rasterize_reference`). Layouts follow nvdiffrast's documented API
so that the adapters (:mod:`glraster.torch`) stay thin; see docs/differentiable.md.
"""
