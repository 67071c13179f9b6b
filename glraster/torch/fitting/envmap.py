"""Recover a Phong material under a cube-map environment from images of it.

Scene (:mod:`glraster.fitting.scenes`): a smooth blob (:func:`blob`, a bumpy UV sphere of
30,720 triangles by default, with vertex normals) at the origin, lit by a procedural studio
sky (:func:`studio_cube_map`, 6 faces of ``env_size``² texels, y up, a sun at
:data:`SUN_DIRECTION`). World and object frame are the same; a view turns the blob by a
uniformly random rotation R in front of a 40 degree camera ``DISTANCE`` away, so the eye
is at e = R^T (0, 0, DISTANCE) in the object frame.

Shading, per pixel, with the material (kd, ks, p) (diffuse and specular RGB, Phong
exponent):

    colour = kd * E(n; coarse) + ks * (E(r) + max(r.l, 0)^p)

n is the interpolated vertex normal, r the interpolated reflection of the view vector
(per vertex v = (e - x)/|e - x|, r = 2 (n.v) n - v), E(d) the cube map looked up in
direction d with ``boundary_mode="cube"``, ``linear-mipmap-linear`` and the directions'
screen derivatives (``uv_da`` from :func:`glraster.torch.interpolate` with
``diff_attrs="all"`` and ``rast_db``). The diffuse lookup adds a mip bias of
log2(env_size) - 2 (a 4² level or coarser: a blurred environment standing in for the
irradiance); the Phong lobe is around the sun direction l, with r normalized per pixel
(and taken as 0 below e^-40: :data:`LOBE_FLOOR`). Pixels the blob does not cover are 0.

Fit: the true material is fixed (kd = (0.60, 0.28, 0.16), ks = (0.30, 0.32, 0.36),
p = 60); the start draws kd uniformly in [0.05, 0.95]³, ks in [0.05, 0.6]³ and p
log-uniformly in [4, 600] (seeded). Every iteration draws ``views`` random rotations (two by
default: one instanced draw), renders the true and the current material in them and takes
one Adam step on the mean squared difference over the covered pixels (:func:`envmap_loss`:
the material enters after the GL ops, so both renders share one rasterize, interpolate and
pair of lookups); the parameters are kd, ks (clamped to [0, 1] after each step; learning
rate ``lr``) and log p (learning rate ``exponent_lr``: the start may be a factor of 15
off, log 15 = 2.7), the learning rates falling exponentially to ``lr_decay`` times their
start over the run. Reported per iteration: the image RMSE of the step's views (covered
pixels), the colour error (mean |c - c_true| over the 6 colour channels) and the relative
exponent error |p - p_true| / p_true.

With ``fit_env`` the cube map is the parameter instead (from a uniform grey start, the
material known): the lighting from the images, each step's backward then running through
both cube lookups and their pyramids. Map and material together are not identifiable: the
map can take up the Phong lobe (ks E(r) + ks max(r.l, 0)^p is matched by other ks, p and a
brighter or dimmer map around l) and kd E(n) trades a factor with the map: fitted
together, the image error falls while the colour and exponent errors grow.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import torch

from glraster import jit
from glraster.fitting.results import EnvmapFit
from glraster.fitting.scenes import SUN_DIRECTION, blob, studio_cube_map
from glraster.torch.fitting.common import Timer, clip_positions, descend
from glraster.torch.fitting.common import quaternion_matrices, random_quaternions, view_matrices
from glraster.torch.ops import interpolate, rasterize
from glraster.torch.texture import texture, texture_construct_mip

__all__ = ["DISTANCE", "EnvmapFit", "FOVY", "LOBE_FLOOR", "TRUE_MATERIAL", "Scene", "Views",
           "envmap_loss", "fit_envmap", "lookups", "make_scene", "render_envmap", "shade",
           "view_setup", "views_of"]

DISTANCE = 3.6
FOVY = 40.0
TRUE_MATERIAL = {"diffuse": (0.60, 0.28, 0.16), "specular": (0.30, 0.32, 0.36),
                 "exponent": 60.0}
# exp(p log x) below e^LOBE_FLOOR (4.2e-18) is taken as 0: exp's results and the backward's
# products of them would otherwise reach float32's subnormal range, whose arithmetic is
# about 70x slower (measured: exp over 2 x 256² pixels 3.7 ms, 0.05 ms without subnormal
# results). The image is unchanged bit for bit wherever E(r) >= 2^-33 (the lobe is then
# below half an ulp of E(r) + lobe; the studio sky is >= 0.1 everywhere), elsewhere by less
# than ks e^-40; the gradient in p loses terms below |dL/dlobe| e^-40 |log x| (|log x| <=
# 13.9, x >= 1e-6) each (tests/torch/test_fit_envmap.py compares both).
LOBE_FLOOR = -40.0
_TRUE = tuple(torch.tensor(v, dtype=torch.float32) for v in TRUE_MATERIAL.values())
_TRUE_VECTOR = np.array([*TRUE_MATERIAL["diffuse"], *TRUE_MATERIAL["specular"],
                         TRUE_MATERIAL["exponent"]], np.float32)
_SUN = np.asarray(SUN_DIRECTION, np.float32)


class Scene:
    """The blob and the environment as float32 torch tensors: ``verts`` (V, 3), ``tri``
    (T, 3) int32, ``normals`` (V, 3), ``env`` (1, 6, N, N, 3); ``mip``: the environment's
    pyramid, built once (it never changes during a fit); :meth:`bias`: the diffuse
    lookup's mip bias image, the same tensor while its shape is (so neither uploaded nor
    validated again)."""

    def __init__(self, glctx, *, mesh=(128, 120), env_size: int = 512):
        verts, faces, normals = blob(*mesh)
        self.verts = torch.tensor(verts, dtype=torch.float32)
        self.tri = torch.tensor(faces, dtype=torch.int32)
        self.normals = torch.tensor(normals, dtype=torch.float32)
        self.env = torch.tensor(studio_cube_map(env_size)[None], dtype=torch.float32)
        self.env_size, self.mesh = env_size, tuple(mesh)
        self.mip = texture_construct_mip(self.env, cube_mode=True, glctx=glctx)
        self._bias = torch.zeros(0)

    def bias(self, shape) -> torch.Tensor:
        """(N, R, R) float32 of log2(env_size) - 2 for images of ``shape`` (N, R, R)."""
        if self._bias.shape != shape or self._bias._version:  # (changed in place: anew)
            self._bias = torch.full(shape, math.log2(self.env_size) - 2.0)
        return self._bias


def make_scene(glctx, *, mesh=(128, 120), env_size: int = 512) -> Scene:
    """:class:`Scene` of a ``mesh[0]`` x ``mesh[1]`` blob (2 mesh[0] mesh[1] triangles) and
    a cube map of ``env_size``² faces."""
    for name, value in (("mesh", min(mesh)), ("env_size", env_size)):
        if value < 2:
            raise ValueError(f"{name} must be at least 2, got {value}")
    return Scene(glctx, mesh=mesh, env_size=env_size)


def view_setup(quaternions):
    """(mvp (N, 4, 4), eye (N, 3)) float32 torch tensors of the views that turn the blob by
    the (N, 4) ``quaternions``."""
    rot = quaternion_matrices(np.asarray(quaternions, np.float64))
    mvp = view_matrices(rot, distance=DISTANCE, fovy=FOVY)
    eye = np.einsum("nji,j->ni", rot, np.array([0.0, 0.0, DISTANCE]))  # R^T (0, 0, d)
    return (torch.tensor(mvp, dtype=torch.float32), torch.tensor(eye, dtype=torch.float32))


class Views(NamedTuple):
    """What the GL ops give for N views, before any lookup or material: ``covered`` (N, R, R)
    bool and as a float32 ``mask`` (N, R, R, 3) of 0 and 1 (one per colour channel: a
    product with it is a plain elementwise one, not a slower broadcast), the interpolated
    normals ``n`` and reflections ``r`` (N, R, R, 3) with their screen derivatives
    ``n_da``, ``r_da`` (N, R, R, 6; (dA/dX, dA/dY) per component), the diffuse lookup's
    mip ``bias`` (N, R, R) and ``log_cos`` (N, R, R, 1): log max(r.l / |r|, 1e-6), the
    Phong lobe's log before the exponent. No gradient flows into any of them (the geometry
    and the views are fixed), so one :func:`views_of` serves the target, the current
    material and a cube map being fitted."""

    covered: torch.Tensor
    mask: torch.Tensor
    n: torch.Tensor
    n_da: torch.Tensor
    r: torch.Tensor
    r_da: torch.Tensor
    bias: torch.Tensor
    log_cos: torch.Tensor


def _gl_views(glctx, scene: Scene, mvp, eye, resolution: int):
    """(rast, pix, pix_da) of the views: rasterize (with rast_db) and interpolate
    (diff_attrs="all") of the normals and the reflections (N, R, R, 6) and their screen
    derivatives (N, R, R, 12; the normal's 3 (dA/dX, dA/dY) pairs, then the
    reflection's)."""
    clip = clip_positions(mvp, scene.verts)
    rast, rast_db = rasterize(glctx, clip, scene.tri, (resolution, resolution), grad_db=True)
    n = scene.normals
    view = eye[:, None, :] - scene.verts[None]                      # (N, V, 3)
    view = view / view.norm(dim=-1, keepdim=True)
    refl = 2.0 * (view * n).sum(-1, keepdim=True) * n - view        # (N, V, 3)
    attrs = torch.cat([n.expand_as(refl), refl], dim=-1).contiguous()
    pix, pix_da = interpolate(attrs, rast, scene.tri, rast_db=rast_db, diff_attrs="all",
                              glctx=glctx)
    return rast, pix, pix_da


def _log_cos(r):
    """log max(r.l / |r|, 1e-6) (..., 1) of the reflections ``r`` (..., 3)."""
    sun = torch.tensor(SUN_DIRECTION, dtype=torch.float32)
    cos = (r * sun).sum(-1, keepdim=True) / r.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    # x^p as exp(p log x), x kept >= 1e-6: pow's gradient in p (x^p log x) is NaN at x = 0
    return torch.log(cos.clamp_min(1e-6))


def views_of(glctx, scene: Scene, mvp, eye, resolution: int) -> Views:
    """:class:`Views` of the (N, 4, 4) ``mvp`` with eyes (N, 3) at ``resolution``²:
    rasterize (with rast_db) and interpolate (diff_attrs="all")."""
    views = _lookup_views(glctx, scene, mvp, eye, resolution)
    covered = views.covered
    mask = covered[..., None].expand(*covered.shape, 3).to(torch.float32)
    return views._replace(mask=mask, log_cos=_log_cos(views.r))


def lookups(glctx, scene: Scene, views: Views, env=None):
    """(E(n; coarse), E(r)), each (N, R, R, 3): the diffuse and mirror lookups of the
    scene's cube map, or of ``env`` (1, 6, N, N, 3; its pyramid built in every call, so
    that the gradient reaches it)."""
    env, mip = (scene.env, scene.mip) if env is None else (env, None)
    lookup = dict(mip=mip, filter_mode="linear-mipmap-linear", boundary_mode="cube",
                  glctx=glctx)
    return (texture(env, views.n, views.n_da, views.bias, **lookup),
            texture(env, views.r, views.r_da, **lookup))


def shade(views: Views, light, diffuse, specular, exponent):
    """(N, R, R, 3) images of the material (``diffuse`` (3,), ``specular`` (3,),
    ``exponent`` scalar tensor) lit by ``light`` (:func:`lookups`), 0 where the blob does
    not cover the pixel."""
    return _unmasked(views, light, diffuse, specular, exponent) * views.mask


def _unmasked(views: Views, light, diffuse, specular, exponent):
    # the Phong lobe exp(p log x) taken as 0 where p log x < LOBE_FLOOR (see its note)
    env_diffuse, env_mirror = light
    power = exponent * views.log_cos
    lobe = torch.exp(power.clamp_min(LOBE_FLOOR)) * (power >= LOBE_FLOOR)
    return diffuse * env_diffuse + specular * (env_mirror + lobe)


def render_envmap(glctx, scene: Scene, mvp, eye, diffuse, specular, exponent,
                  resolution: int, *, env=None):
    """(N, R, R, 3) images of the material (``diffuse`` (3,), ``specular`` (3,),
    ``exponent`` scalar tensor) under the (N, 4, 4) ``mvp`` with eyes (N, 3), and the
    (N, R, R) coverage: :func:`views_of`, :func:`lookups` (of ``env`` when given) and
    :func:`shade`. Differentiable in the material and ``env``."""
    views = views_of(glctx, scene, mvp, eye, resolution)
    return shade(views, lookups(glctx, scene, views, env), diffuse, specular,
                 exponent), views.covered


@jit.njit(nogil=True, error_model="numpy")
def _loss_kernel(covered, t_diffuse, t_mirror, e_diffuse, e_mirror, r, sun, true, material,
                 grads, image_grads):
    """The loss of :func:`envmap_loss` and its gradients in one pass over the P pixels.

    covered (P,) bool; t_diffuse, t_mirror, e_diffuse, e_mirror, r (P, 3) float32: the
    lookups (E(n), E(r)) of the target and of the fit, and the interpolated reflections;
    sun (3,), true and material (7,) float32: (kd, ks, p);
    grads (7,) float64: written, d loss / d (kd, ks, p); image_grads (2, P, 3) float32 or
    (0, 0, 3): written when not empty, d loss / d (e_diffuse, e_mirror) (0 off the blob).
    Each pixel in float32 as :func:`_unmasked` (and :func:`_log_cos`); the sums in float64
    in pixel order (serial: deterministic). Returns (loss, K)."""
    floor = np.float32(LOBE_FLOOR)
    # first pass: the count, for the mean's 1 / (3 K)
    k = 0
    for i in range(covered.shape[0]):
        if covered[i]:
            k += 1
    scale = 2.0 / (3.0 * max(k, 1))
    total = 0.0
    for j in range(7):
        grads[j] = 0.0
    want_images = image_grads.shape[1] > 0
    if want_images:
        image_grads[:] = 0.0
    for i in range(covered.shape[0]):
        if not covered[i]:
            continue
        x, y, z = r[i, 0], r[i, 1], r[i, 2]
        norm = np.float32(math.sqrt(x * x + y * y + z * z))
        cos = (x * sun[0] + y * sun[1] + z * sun[2]) / max(norm, np.float32(1e-12))
        log_cos = np.float32(math.log(max(cos, np.float32(1e-6))))
        power_t = true[6] * log_cos
        lobe_t = np.float32(math.exp(power_t)) if power_t >= floor else np.float32(0.0)
        power = material[6] * log_cos
        lobe = np.float32(math.exp(power)) if power >= floor else np.float32(0.0)
        dlobe = 0.0
        for c in range(3):
            target = true[c] * t_diffuse[i, c] + true[3 + c] * (t_mirror[i, c] + lobe_t)
            ed, em = e_diffuse[i, c], e_mirror[i, c]
            spec = em + lobe
            d = np.float64((material[c] * ed + material[3 + c] * spec) - target)
            total += d * d
            grads[c] += d * ed
            grads[3 + c] += d * spec
            dlobe += d * material[3 + c]
            if want_images:
                image_grads[0, i, c] = np.float32(scale * d * material[c])
                image_grads[1, i, c] = np.float32(scale * d * material[3 + c])
        grads[6] += dlobe * lobe * log_cos
    for j in range(7):
        grads[j] *= scale
    return total / (3.0 * max(k, 1)), k


class _EnvmapLoss(torch.autograd.Function):
    """:func:`_loss_kernel` as an autograd function of (kd, ks, p, E(n), E(r)) (and of
    nothing else: ``true_light``, the target's lookups, ``r`` and ``covered``
    are constants): the forward computes the gradients too (every call is
    differentiated), the backward scales them."""

    @staticmethod
    def forward(ctx, kd, ks, p, e_diffuse, e_mirror, true_light, r, covered):
        material = torch.cat([kd.detach(), ks.detach(), p.detach().reshape(1)])
        pixels = covered.numel()
        want_images = any(ctx.needs_input_grad[3:5])
        grads = np.empty(7, np.float64)
        image_grads = np.empty((2, pixels, 3) if want_images else (0, 0, 3), np.float32)
        loss, _ = _loss_kernel(covered.reshape(-1).numpy(),
                               *(x.reshape(-1, 3).numpy() for x in true_light),
                               e_diffuse.detach().reshape(-1, 3).numpy(),
                               e_mirror.detach().reshape(-1, 3).numpy(),
                               r.reshape(-1, 3).numpy(), _SUN, _TRUE_VECTOR,
                               material.numpy(), grads, image_grads)
        ctx.grads, ctx.shape = torch.from_numpy(grads.astype(np.float32)), e_diffuse.shape
        ctx.image_grads = torch.from_numpy(image_grads) if want_images else None
        return torch.tensor(loss, dtype=torch.float32)

    @staticmethod
    def backward(ctx, grad):
        g = ctx.grads * grad
        images = (None, None) if ctx.image_grads is None else \
            tuple((x * grad).reshape(ctx.shape) for x in ctx.image_grads)
        return g[:3], g[3:6], g[6], *images, None, None, None


def envmap_loss(glctx, scene: Scene, mvp, eye, material, resolution: int, *, env=None,
                timer=None):
    """The masked MSE of one step: the views rendered once (:func:`views_of`), the target
    shaded under the true material, the ``material`` (diffuse, specular, exponent) under
    the scene's cube map or ``env``: after the lookups one compiled pass over the pixels
    shades both on the covered ones and sums the loss and its gradients
    (:func:`_loss_kernel`; each pixel's values as :func:`shade`'s in float32, the sums in
    float64). timer: a :class:`glraster.torch.fitting.common.Timer`, charged "target"
    (views and the target's lookups) and "forward"."""
    timer = timer or Timer()
    with timer("target"), torch.no_grad():
        views = _lookup_views(glctx, scene, mvp, eye, resolution)
        light = lookups(glctx, scene, views)
    with timer("forward"):
        true_light = light
        if env is not None:
            light = lookups(glctx, scene, views, env)
        kd, ks, p = material
        return _EnvmapLoss.apply(kd, ks, p, *light, true_light, views.r, views.covered)


@jit.njit(nogil=True)
def _split(pix, pix_da, n, r, n_da, r_da):
    """The normals' and the reflections' channels of the P interpolated pixels ``pix``
    (P, 6) and their derivatives ``pix_da`` (P, 12) into ``n``, ``r`` (P, 3) and ``n_da``,
    ``r_da`` (P, 6): one pass (copies, the same bits; measured 1.2 to 1.5 ms for 2 x 256²
    pixels, 2.1 to 4.5 ms for the four torch ``contiguous`` slices)."""
    for i in range(pix.shape[0]):
        for c in range(3):
            n[i, c] = pix[i, c]
            r[i, c] = pix[i, 3 + c]
        for c in range(6):
            n_da[i, c] = pix_da[i, c]
            r_da[i, c] = pix_da[i, 6 + c]


def _lookup_views(glctx, scene: Scene, mvp, eye, resolution: int) -> Views:
    """:class:`Views` with what :func:`lookups` reads (``covered`` (N, R, R), the normals
    and reflections, their derivatives and the bias); ``mask`` and ``log_cos`` None."""
    rast, pix, pix_da = _gl_views(glctx, scene, mvp, eye, resolution)
    n_pix, r_pix, n_da, r_da = (torch.empty(pix.shape[:-1] + (k,), dtype=pix.dtype)
                                for k in (3, 3, 6, 6))
    _split(*(x.detach().numpy().reshape(-1, x.shape[-1])
             for x in (pix, pix_da, n_pix, r_pix, n_da, r_da)))
    return Views(covered=rast[..., 3] > 0, mask=None, n=n_pix, n_da=n_da, r=r_pix,
                 r_da=r_da, bias=scene.bias(n_pix.shape[:-1]), log_cos=None)


def fit_envmap(glctx, seed: int, *, resolution: int = 256, iterations: int = 300,
               views: int = 2, mesh=(128, 120), env_size: int = 512, lr: float = 0.06,
               exponent_lr: float = 0.15, lr_decay: float = 0.1, fit_env: bool = False,
               env_lr: float = 0.06, scene: Scene | None = None,
               progress=None) -> EnvmapFit:
    """Fit the material from the random start of ``seed`` (see the module doc).

    glctx: a :class:`glraster.torch.RasterizeGLContext`; scene: a :func:`make_scene` of
    ``mesh`` and ``env_size`` (made here when None). fit_env: fit the cube map instead,
    from a uniform grey (0.3) start (learning rate ``env_lr``, texels clamped to >= 0),
    under the true material (the module doc says why not both).
    progress: optional callable ``(i, total, label)``, called every iteration."""
    for name, value in (("resolution", resolution), ("iterations", iterations),
                        ("views", views)):
        if value < 1:
            raise ValueError(f"{name} must be >= 1, got {value}")
    scene = scene or make_scene(glctx, mesh=mesh, env_size=env_size)
    true = {k: torch.tensor(v, dtype=torch.float32) for k, v in TRUE_MATERIAL.items()}
    rng = np.random.default_rng(seed)
    start = {"diffuse": rng.uniform(0.05, 0.95, 3), "specular": rng.uniform(0.05, 0.6, 3),
             "exponent": float(np.exp(rng.uniform(np.log(4.0), np.log(600.0))))}
    kd = torch.tensor(start["diffuse"], dtype=torch.float32, requires_grad=True)
    ks = torch.tensor(start["specular"], dtype=torch.float32, requires_grad=True)
    log_p = torch.tensor(math.log(start["exponent"]), dtype=torch.float32,
                         requires_grad=True)
    env = None
    if fit_env:  # the lighting, under the known material
        with torch.no_grad():
            kd.copy_(true["diffuse"])
            ks.copy_(true["specular"])
            log_p.fill_(math.log(TRUE_MATERIAL["exponent"]))
        for fixed in (kd, ks, log_p):
            fixed.requires_grad_(False)
        start = {k: np.asarray(v, np.float64) for k, v in TRUE_MATERIAL.items()}
        env = torch.full_like(scene.env, 0.3).requires_grad_(True)
        groups = [{"params": [env], "lr": env_lr}]
    else:
        groups = [{"params": [kd, ks]}, {"params": [log_p], "lr": exponent_lr}]
    opt = torch.optim.Adam(groups, lr=lr)
    schedule = torch.optim.lr_scheduler.LambdaLR(
        opt, lambda it: lr_decay ** (it / max(iterations, 1)))
    timer = Timer()
    rmse, color_error, exponent_error, env_rmse = [], [], [], []
    p_true = TRUE_MATERIAL["exponent"]

    def measure():
        with torch.no_grad():
            err = torch.cat([kd - true["diffuse"], ks - true["specular"]]).abs().mean()
            color_error.append(float(err))
            exponent_error.append(abs(math.exp(float(log_p.detach())) - p_true) / p_true)
            if env is not None:
                env_rmse.append(float(torch.sqrt(torch.mean((env - scene.env) ** 2))))

    def project():
        kd.clamp_(0.0, 1.0)
        ks.clamp_(0.0, 1.0)
        if env is not None:
            env.clamp_(min=0.0)

    for it in range(iterations):
        measure()
        mvp, eye = view_setup(random_quaternions(rng, views))
        loss = envmap_loss(glctx, scene, mvp, eye, (kd, ks, torch.exp(log_p)), resolution,
                           env=env, timer=timer)
        descend(timer, loss, opt, schedule, project=project)
        rmse.append(math.sqrt(float(loss.detach())))
        if progress is not None:
            progress(it + 1, iterations, f"seed {seed} RMSE {rmse[-1]:.4f} colour "
                                         f"{color_error[-1]:.3f} exponent "
                                         f"{exponent_error[-1]:.3f}"
                                         + (f" env {env_rmse[-1]:.3f}" if fit_env else ""))
    measure()
    final = {"diffuse": kd.detach().double().numpy(), "specular": ks.detach().double().numpy(),
             "exponent": math.exp(float(log_p.detach()))}
    return EnvmapFit(seed=seed, resolution=resolution, iterations=iterations, views=views,
                     env_size=scene.env_size, mesh=scene.mesh,
                     image_rmse=np.array(rmse), color_error=np.array(color_error),
                     exponent_error=np.array(exponent_error),
                     env_rmse=np.array(env_rmse),
                     final_env=None if env is None else env.detach()[0].numpy(),
                     true={k: np.asarray(v, np.float64) for k, v in TRUE_MATERIAL.items()},
                     start=start, final=final, timing=timer.summary())
