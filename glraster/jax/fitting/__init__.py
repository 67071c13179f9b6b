"""Inverse rendering with glraster.jax: the fits of
:mod:`glraster.torch.fitting`, written in JAX (optax's Adam), with the same scenes, random
draws, schedules and result records (:mod:`glraster.fitting`).

- :func:`fit_cube`: a cube's 8 vertex positions and colours from a random start;
- :func:`fit_pose`: a cube's rotation from one image, with restarts and symmetry jumps;
- :func:`fit_texture`: a procedural texture on a sphere, mipmapped or bilinear.

``glraster fit cube|pose|texture --framework jax`` runs them (docs/jax.md).
"""

from glraster.jax.fitting.cube import fit_cube
from glraster.jax.fitting.pose import fit_pose
from glraster.jax.fitting.texture import fit_texture

__all__ = ["fit_cube", "fit_pose", "fit_texture"]
