"""Inverse rendering with glraster.torch: fits that recover a scene from its images.

- :func:`fit_cube`: a cube's 8 vertex positions and colours from a random start, by an image
  loss through rasterize -> interpolate -> antialias at a few pixels;
- :func:`fit_pose`: a cube's rotation (a quaternion) from one image, with random restarts;
- :func:`fit_texture`: a procedural texture on a sphere, with mipmapped
  (linear-mipmap-linear, uv_da from interpolate) or plain bilinear lookups;
- :func:`fit_envmap`: a Phong material (diffuse and specular colour, exponent) on a blob
  under a cube-map environment (two cube lookups with uv_da per pixel).

Each returns a dataclass with the error curves, the start and the result, and the time per
iteration split into forward and backward; :mod:`glraster.torch.fitting.figures` draws the
curves and the before/after pictures. ``glraster fit cube|pose|texture|envmap`` runs them
(docs/fitting.md).
"""

from glraster.torch.fitting.cube import CubeFit, fit_cube
from glraster.torch.fitting.envmap import EnvmapFit, fit_envmap
from glraster.torch.fitting.pose import PoseFit, fit_pose
from glraster.torch.fitting.texture import TextureFit, fit_texture

__all__ = ["CubeFit", "EnvmapFit", "PoseFit", "TextureFit", "fit_cube", "fit_envmap",
           "fit_pose", "fit_texture"]
