"""The records of one fit run (NumPy arrays, float64), the same from every front end:
:class:`CubeFit`, :class:`PoseFit`, :class:`TextureFit` and :class:`EnvmapFit`, each with
the JSON ``summary()`` that ``glraster fit --json`` writes."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from glraster.fitting.scenes import first_below

__all__ = ["CubeFit", "EnvmapFit", "PoseFit", "TextureFit"]


@dataclass
class CubeFit:
    """One run of :func:`fit_cube`. Arrays are float64 NumPy."""

    resolution: int
    seed: int
    iterations: int
    views: int
    antialias: bool
    error: np.ndarray        # (iterations + 1,) mean vertex distance before each step
    color_error: np.ndarray  # (iterations + 1,) mean |colour - true colour| per vertex
    loss: np.ndarray         # (iterations,) image loss of each step
    true_pos: np.ndarray
    true_col: np.ndarray
    start_pos: np.ndarray
    start_col: np.ndarray
    final_pos: np.ndarray
    final_col: np.ndarray
    timing: dict = field(default_factory=dict)

    def summary(self) -> dict:
        return {"resolution": self.resolution, "seed": self.seed,
                "iterations": self.iterations, "views": self.views,
                "antialias": self.antialias, "start_error": float(self.error[0]),
                "final_error": float(self.error[-1]),
                "final_color_error": float(self.color_error[-1]),
                "first_below_0.05": first_below(self.error, 0.05),
                "final_loss": float(self.loss[-1]) if len(self.loss) else None,
                "first_loss_below_0.01": first_below(self.loss, 0.01),
                "timing": self.timing}


@dataclass
class PoseFit:
    """One run of :func:`fit_pose`. Arrays are float64 NumPy."""

    seed: int
    resolution: int
    iterations: int
    restarts: int
    antialias: bool
    target: np.ndarray      # (4,) the true quaternion
    start: np.ndarray       # (restarts, 4)
    final: np.ndarray       # (restarts, 4), normalized
    angle: np.ndarray       # (iterations + 1, restarts) degrees from the truth
    loss: np.ndarray        # (iterations, restarts) image loss of each restart
    best: int               # the restart with the lowest final loss
    final_loss: np.ndarray  # (restarts,) loss at the final parameters
    jumps: list = field(default_factory=list)  # [(iteration, [symmetry index per restart])]
    timing: dict = field(default_factory=dict)

    @property
    def best_angle(self) -> float:
        return float(self.angle[-1, self.best])

    def summary(self) -> dict:
        return {"seed": self.seed, "resolution": self.resolution,
                "iterations": self.iterations, "restarts": self.restarts,
                "antialias": self.antialias, "jumps": self.jumps, "best_restart": self.best,
                "final_angle_deg": self.best_angle,
                "start_angle_deg_of_best": float(self.angle[0, self.best]),
                "restarts_within_5deg": int(np.sum(self.angle[-1] < 5.0)),
                "final_angles_deg": [float(a) for a in self.angle[-1]],
                "timing": self.timing}


@dataclass
class TextureFit:
    """One run of :func:`fit_texture`."""

    seed: int
    mip: bool
    resolution: int
    iterations: int
    views: int
    texture_size: int
    eval_iterations: np.ndarray  # (K,)
    eval_psnr: np.ndarray        # (K,) held-out image PSNR, dB
    texture_psnr: np.ndarray     # (K,) texture against the truth, dB
    loss: np.ndarray             # (iterations,)
    final: np.ndarray            # (Ht, Wt, 3) the fitted texture, float64
    timing: dict = field(default_factory=dict)

    def summary(self) -> dict:
        return {"seed": self.seed, "mip": self.mip,
                "filter_mode": "linear-mipmap-linear" if self.mip else "linear",
                "resolution": self.resolution, "iterations": self.iterations,
                "views": self.views, "texture_size": self.texture_size,
                "final_image_psnr_db": float(self.eval_psnr[-1]),
                "final_texture_psnr_db": float(self.texture_psnr[-1]), "timing": self.timing}


@dataclass
class EnvmapFit:
    """One run of :func:`fit_envmap`: a Phong material (diffuse and specular colours, an
    exponent) under a cube-map environment. Arrays are float64 NumPy."""

    seed: int
    resolution: int
    iterations: int
    views: int
    env_size: int
    mesh: tuple                 # (nu, nv) of the blob: 2 nu nv triangles
    image_rmse: np.ndarray      # (iterations,) RMSE over covered pixels of each step's views
    color_error: np.ndarray     # (iterations + 1,) mean |colour - true| over kd and ks
    exponent_error: np.ndarray  # (iterations + 1,) |exponent - true| / true
    true: dict                  # {"diffuse": (3,), "specular": (3,), "exponent": float}
    start: dict
    final: dict
    env_rmse: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (iterations + 1,)
    # with fit_env: RMSE of the fitted cube map's texels against the truth; else empty
    final_env: np.ndarray | None = None  # with fit_env: (6, N, N, 3) float32
    timing: dict = field(default_factory=dict)

    @property
    def fit_env(self) -> bool:
        return self.final_env is not None

    def summary(self) -> dict:
        plain = lambda m: {k: (np.asarray(v).tolist()) for k, v in m.items()}  # noqa: E731
        return {"seed": self.seed, "resolution": self.resolution,
                "iterations": self.iterations, "views": self.views,
                "env_size": self.env_size, "mesh": list(self.mesh),
                "triangles": 2 * self.mesh[0] * self.mesh[1],
                "start_image_rmse": float(self.image_rmse[0]),
                "final_image_rmse": float(self.image_rmse[-1]),
                "start_color_error": float(self.color_error[0]),
                "final_color_error": float(self.color_error[-1]),
                "start_exponent_error": float(self.exponent_error[0]),
                "final_exponent_error": float(self.exponent_error[-1]),
                "fit_env": self.fit_env,
                "start_env_rmse": float(self.env_rmse[0]) if self.fit_env else None,
                "final_env_rmse": float(self.env_rmse[-1]) if self.fit_env else None,
                "true": plain(self.true), "start": plain(self.start),
                "final": plain(self.final), "timing": self.timing}
