"""Second-order spherical harmonics and the paper's diffuse convolution (SOLID-Net §4.3).

The formulas are written once through the array API (see :mod:`solidkit.envmap.coords`):
NumPy arrays in, NumPy arrays out; torch tensors in (any device, batched, differentiable),
tensors out.

Basis
    The paper's unnormalised second-order basis, for a unit normal ``n = (x, y, z)`` in the
    panorama frame (docs/conventions.md §2: x right, y down, z forward)::

        b(n) = [1, x, y, z, 3z^2 - 1, xy, xz, yz, x^2 - y^2]

    Each ``b_k`` is a constant multiple of an orthonormal real spherical harmonic
    (Ramamoorthi & Hanrahan 2001, "An efficient representation for irradiance environment
    maps", eq. 3, with z as the polar axis): ``Y_k(n) = SH_ORTHONORMAL_SCALE[k] * b_k(n)``, where
    ``Y_k`` is ``Y_{l,m}`` with ``(l, m) = SH_LM[k]``. So ``b`` is orthogonal but not normalised:
    ``int b b^T dw = SH_GRAM = diag(1 / SH_ORTHONORMAL_SCALE**2)``. Coefficients convert as
    ``L_orthonormal = L / SH_ORTHONORMAL_SCALE`` (and back by multiplying).

Coefficients
    ``L`` has shape ``(..., C, 9)``: one row of 9 coefficients per colour channel (the paper's
    ``L in R^{3x9}``); the map they describe is ``f(n) = L @ b(n)``.

Panorama layouts (one per backend)
    * NumPy: channels last, ``(..., H, W, C)`` (as read by :mod:`solidkit.envmap.io`, OpenCV);
    * torch: channels first, ``(..., C, H, W)`` (kornia; typically ``(B, C, H, W)``).

    Panoramas are equirectangular with ``W = 2H`` (conventions §3). Functions that return a
    panorama return it in the layout of their backend.

Lambertian filtering and the paper's ``D``
    The paper's diffuse convolution (§4.3, eq. 6) is a cosine-weighted hemisphere *mean*::

        D(H, i) = (1 / K_i) sum_{w in Omega_i} H(w) s(w) (w . n_i),  K_i = sum_{w in Omega_i} s(w)

    with ``Omega_i`` the pixels in the hemisphere around ``n_i`` (``w . n_i > 0``) and ``s`` the
    pixel solid angle. ``K_i -> 2 pi``, so ``D = E / (2 pi)`` where ``E(n) = int H(w) max(w.n, 0) dw``
    is the irradiance: a constant map ``H = c`` gives ``D = c / 2`` (``E = pi c``), a linear map
    ``H(w) = a . w`` gives ``D = (a . n) / 3`` (``E = 2 pi (a . n) / 3``). In SH the cosine filter
    multiplies band ``l`` by ``A_l = (pi, 2 pi / 3, pi / 4)`` (Ramamoorthi & Hanrahan 2001, eq. 8);
    since ``b`` only rescales each ``Y_lm``, the same factors act on ``L`` directly.
    :func:`sh_irradiance` returns the coefficients of ``D`` by default (``kind="mean"``:
    ``A_l / 2 pi = (1/2, 1/3, 1/8)``), so that ``sh_render(sh_irradiance(sh_project(H)), n)``
    approximates ``diffuse_convolution(H)`` (the paper's ``L_dif``).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Callable
from functools import lru_cache
from typing import Any, Literal

import array_api_compat
import numpy as np

from solidkit.envmap.coords import angles_from_coords, direction_grid, namespace, solid_angle
from solidkit.envmap.resample import resize
from solidkit.errors import InputError, PanoramaError

__all__ = [
    "SH_LM",
    "SH_BANDS",
    "SH_ORTHONORMAL_SCALE",
    "SH_GRAM",
    "LAMBERT_BAND_FACTORS",
    "sh_basis",
    "sh_project",
    "sh_render",
    "sh_irradiance",
    "lambertian_sphere",
    "diffuse_convolution",
]

#: ``(l, m)`` of the orthonormal real SH (Ramamoorthi & Hanrahan 2001) matching each entry of ``b``.
SH_LM: tuple[tuple[int, int], ...] = ((0, 0), (1, 1), (1, -1), (1, 0), (2, 0), (2, -2), (2, 1), (2, -1), (2, 2))

#: Band ``l`` of each of the 9 basis functions.
SH_BANDS: tuple[int, ...] = tuple(lm[0] for lm in SH_LM)

_PI = math.pi
#: ``Y_k = SH_ORTHONORMAL_SCALE[k] * b_k``: 0.282095, 0.488603 (x3), 0.315392, 1.092548 (x3), 0.546274.
SH_ORTHONORMAL_SCALE: np.ndarray = np.array(
    [
        1 / (2 * math.sqrt(_PI)),  # Y00 = 0.282095
        math.sqrt(3 / (4 * _PI)),  # Y11 = 0.488603 x
        math.sqrt(3 / (4 * _PI)),  # Y1-1 = 0.488603 y
        math.sqrt(3 / (4 * _PI)),  # Y10 = 0.488603 z
        math.sqrt(5 / (16 * _PI)),  # Y20 = 0.315392 (3z^2 - 1)
        math.sqrt(15 / (4 * _PI)),  # Y2-2 = 1.092548 xy
        math.sqrt(15 / (4 * _PI)),  # Y21 = 1.092548 xz
        math.sqrt(15 / (4 * _PI)),  # Y2-1 = 1.092548 yz
        math.sqrt(15 / (16 * _PI)),  # Y22 = 0.546274 (x^2 - y^2)
    ]
)
SH_ORTHONORMAL_SCALE.flags.writeable = False

#: Continuous Gram matrix ``int b b^T dw`` (steradians): diag(4pi, 4pi/3 x3, 16pi/5, 4pi/15 x3, 16pi/15).
SH_GRAM: np.ndarray = np.diag(1.0 / SH_ORTHONORMAL_SCALE**2)
SH_GRAM.flags.writeable = False

#: Per-band factors of the clamped-cosine (Lambertian) filter, for each ``kind`` of :func:`sh_irradiance`.
LAMBERT_BAND_FACTORS: dict[str, tuple[float, float, float]] = {
    "irradiance": (_PI, 2 * _PI / 3, _PI / 4),  # E(n)
    "radiance": (1.0, 2 / 3, 1 / 4),  # E(n) / pi: radiance leaving a white Lambertian surface
    "mean": (1 / 2, 1 / 3, 1 / 8),  # E(n) / 2pi: the paper's D(H, i)
}

# Largest panorama height for the exact full-grid diffuse convolution (its operator has
# 2H * H * H entries: 16.8 MB in float32 at H = 128, 134 MB at H = 256).
MAX_EXACT_HEIGHT = 256
_CHUNK = 1 << 22  # elements of a (normals x pixels) cosine block in the explicit-normals path
# Pixels with |w . n| <= _TIE lie on the hemisphere's boundary great circle (exact ties occur on
# the grid: e.g. mirrored rows); they count half in K_i, so both D paths and backends agree.
_TIE = 1e-6


# --------------------------------------------------------------------------------------------
# layouts, validation, caches


def _is_torch(x: Any) -> bool:
    return array_api_compat.is_torch_array(x)


def _float(x: Any, xp: Any) -> Any:
    if xp.isdtype(x.dtype, "real floating"):
        return x
    return xp.astype(x, xp.float32 if _is_torch(x) else xp.float64)


def _channels_first(pano: Any, name: str = "panorama") -> tuple[Any, Any]:
    """``pano`` as ``(..., C, H, W)`` floating point, and its namespace; checks ``W = 2H``."""
    xp = namespace(pano)
    if pano.ndim < 3:
        layout = "(..., C, H, W)" if _is_torch(pano) else "(..., H, W, C)"
        raise PanoramaError(f"{name}: expected a {layout} panorama, got shape {tuple(pano.shape)}")
    if not _is_torch(pano):
        pano = xp.moveaxis(pano, -1, -3)
    h, w = pano.shape[-2], pano.shape[-1]
    if w != 2 * h or h < 1:
        raise PanoramaError(f"{name}: not an equirectangular panorama: {w}x{h} (width must be 2 x height)")
    return _float(pano, xp), xp


def _to_layout(x_cf: Any, like: Any, xp: Any) -> Any:
    """``(..., C, H, W)`` back to the layout of ``like``'s backend."""
    return x_cf if _is_torch(like) else xp.moveaxis(x_cf, -3, -1)


_CACHE: OrderedDict[tuple[Any, ...], Any] = OrderedDict()
_CACHE_SIZE = 16


def _cached(name: str, height: int, builder: Callable[[int], Any], like: Any, xp: Any) -> Any:
    """``builder(height)`` (float64 NumPy, or a tuple of them) converted to ``like``'s backend,
    device and dtype; kept in a small LRU cache keyed by (name, height, backend, device, dtype)."""
    dev = array_api_compat.device(like)
    key = (name, height, "torch" if _is_torch(like) else "numpy", str(dev), str(like.dtype))
    hit = _CACHE.get(key)
    if hit is not None:
        _CACHE.move_to_end(key)
        return hit
    value = builder(height)

    def conv(a: Any) -> Any:
        return xp.asarray(a, dtype=like.dtype, device=dev)

    value = tuple(conv(a) for a in value) if isinstance(value, tuple) else conv(value)
    _CACHE[key] = value
    if len(_CACHE) > _CACHE_SIZE:
        _CACHE.popitem(last=False)
    return value


def _working(pano: Any, height: int | None) -> tuple[Any, Any]:
    """``pano`` at the working ``height`` (energy-preserving :func:`~solidkit.envmap.resample.resize`),
    channels first ``(..., C, h, 2h)``, and its namespace."""
    x, xp = _channels_first(pano)
    if height is None or height == x.shape[-2]:
        return x, xp
    if not isinstance(height, int) or height < 1:
        raise InputError(f"working height must be a positive integer, got {height!r}")
    if _is_torch(x):
        return resize(x, height), xp
    # NumPy resize takes (H, W, C): fold any leading batch dimensions into the channels
    lead, (c, h) = tuple(x.shape[:-3]), x.shape[-3:-1]
    folded = xp.moveaxis(xp.reshape(x, (-1, h, 2 * h)), 0, -1)  # (H, W, N*C)
    small = xp.moveaxis(resize(folded, height), -1, 0)
    return xp.reshape(small, lead + (c, height, 2 * height)), xp


# --------------------------------------------------------------------------------------------
# basis, projection, rendering


def sh_basis(n: Any) -> Any:
    """The paper's second-order SH basis ``b(n)`` (§4.3), shape ``(..., 9)``.

    ``b(n) = [1, nx, ny, nz, 3 nz^2 - 1, nx ny, nx nz, ny nz, nx^2 - ny^2]`` for unit normals
    ``n (..., 3)`` in the panorama frame (x right, y down, z forward). ``n`` is not renormalised
    (the basis is a polynomial; gradients flow to ``n``). ``SH_ORTHONORMAL_SCALE * b`` are the
    orthonormal real SH of Ramamoorthi & Hanrahan (2001).

    Examples
    --------
    >>> b = sh_basis(np.array([0.0, 0.0, 1.0]))
    >>> b.shape
    (9,)
    >>> np.round(b, 6)
    array([1., 0., 0., 1., 2., 0., 0., 0., 0.])
    """
    xp = namespace(n)
    x, y, z = n[..., 0], n[..., 1], n[..., 2]
    return xp.stack([xp.ones_like(x), x, y, z, 3 * z * z - 1, x * y, x * z, y * z, x * x - y * y], axis=-1)


@lru_cache(maxsize=4)
def _basis_grid_np(height: int) -> np.ndarray:
    return np.reshape(sh_basis(direction_grid(height)), (-1, 9))


@lru_cache(maxsize=4)
def _projector_np(height: int) -> np.ndarray:
    """``(H W, 9)`` matrix ``P`` with ``L = pano (C, HW) @ P``: weighted least squares on ``b``."""
    basis = _basis_grid_np(height)
    w = np.reshape(solid_angle(height), (-1, 1))
    gram = basis.T @ (w * basis)  # discrete version of SH_GRAM
    return np.linalg.solve(gram, (w * basis).T).T


def sh_project(pano: Any, height: int | None = None) -> Any:
    """Second-order SH coefficients ``L (..., C, 9)`` of an equirectangular panorama.

    The least-squares fit of ``L @ b(d)`` to the panorama under the pixel solid angles
    (``min sum_pixels s(d) |pano(d) - L b(d)|^2``): ``L = (sum s pano b^T) G^-1`` with the discrete
    Gram matrix ``G = sum s b b^T`` (``b`` is not orthonormal; ``G`` approximates :data:`SH_GRAM`).
    A panorama that is exactly ``L @ b(d)`` at its pixel centres gives back ``L``.

    Parameters
    ----------
    pano : array
        NumPy ``(..., H, 2H, C)`` or torch ``(..., C, H, 2H)``, linear radiance.
    height : int, optional
        Working resolution: the panorama is first resized to this height with the energy-preserving
        :func:`~solidkit.envmap.resample.resize`. Default: the panorama's own.

    Returns
    -------
    array ``(..., C, 9)``, same backend, dtype and device as ``pano``.

    Examples
    --------
    >>> sky = np.full((32, 64, 3), 2.0, np.float32)  # a constant sky of radiance 2
    >>> L = sh_project(sky)
    >>> L.shape
    (3, 9)
    >>> np.round(L[0], 3) + 0.0  # only the constant band
    array([2., 0., 0., 0., 0., 0., 0., 0., 0.], dtype=float32)
    """
    x, xp = _working(pano, height)
    h = x.shape[-2]
    proj = _cached("projector", h, _projector_np, x, xp)
    flat = xp.reshape(x, tuple(x.shape[:-2]) + (h * 2 * h,))
    return flat @ proj


def sh_render(L: Any, n: Any) -> Any:
    """Value of the SH map ``L`` at unit directions ``n``: ``L @ b(n)``, shape ``(..., C)``.

    ``L (..., C, 9)`` and ``n (..., 3)``; the leading dimensions broadcast like a matmul batch
    (for an ``(H, W)`` image of normals and one ``L (C, 9)`` use ``L`` as is; for ``L (B, C, 9)``
    and normals ``(B, H, W, 3)`` pass ``L[:, None, None]``).

    Examples
    --------
    >>> L = sh_project(np.full((32, 64, 1), 2.0, np.float32))
    >>> np.round(sh_render(L, np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])), 3)  # 2 in every direction
    array([[2.],
           [2.]])
    """
    return (L @ sh_basis(n)[..., :, None])[..., 0]


def sh_irradiance(L: Any, kind: Literal["mean", "irradiance", "radiance"] = "mean") -> Any:
    """Coefficients ``(..., C, 9)`` of the Lambertian (clamped-cosine) filtered map of ``L``.

    Multiplies band ``l`` by ``LAMBERT_BAND_FACTORS[kind][l]`` (Ramamoorthi & Hanrahan 2001):

    * ``"mean"`` (default): ``E(n) / 2 pi``, the cosine-weighted hemisphere mean, i.e. the
      paper's diffuse convolution ``D(H, i)`` (§4.3); a constant ``c`` gives ``c / 2``;
    * ``"irradiance"``: ``E(n) = int L(w) max(w.n, 0) dw``; a constant ``c`` gives ``pi c``;
    * ``"radiance"``: ``E(n) / pi``, the radiance of a white Lambertian surface; ``c`` gives ``c``.

    Examples
    --------
    >>> L = sh_project(np.full((32, 64, 1), 2.0, np.float32))
    >>> np.round(sh_irradiance(L)[0, :3], 6)  # 'mean': the cosine-weighted hemisphere mean is c / 2
    array([1., 0., 0.], dtype=float32)
    """
    if kind not in LAMBERT_BAND_FACTORS:
        raise InputError(f"unknown kind {kind!r}; expected one of {sorted(LAMBERT_BAND_FACTORS)}")
    xp = namespace(L)
    a = LAMBERT_BAND_FACTORS[kind]
    factors = xp.asarray([a[band] for band in SH_BANDS], dtype=L.dtype, device=array_api_compat.device(L))
    return L * factors


def lambertian_sphere(L: Any, height: int, albedo: Any = None) -> Any:
    """The relit Lambertian sphere of the paper's ``L_dif``: ``diag(albedo) L b(N_ll)`` over the
    equirect grid of the given height (``N_ll(i)`` = the direction of pixel ``i``).

    Parameters
    ----------
    L : array ``(..., C, 9)``
        SH coefficients (of the already filtered map: e.g. the network's ``P_SH``, or
        ``sh_irradiance(sh_project(H))``).
    height : int
        Panorama height ``H`` (width ``2H``).
    albedo : array ``(C,)`` or ``(..., C)``, optional
        The paper's ``alpha_o``; default ``[1, ..., 1]``.

    Returns
    -------
    NumPy ``(..., H, 2H, C)`` or torch ``(..., C, H, 2H)``.

    Examples
    --------
    >>> L = sh_irradiance(sh_project(np.full((32, 64, 3), 2.0, np.float32)))
    >>> sphere = lambertian_sphere(L, 8)
    >>> sphere.shape
    (8, 16, 3)
    >>> np.round(sphere[4, 8], 3)  # c / 2 for every normal of the sphere
    array([1., 1., 1.], dtype=float32)
    """
    xp = namespace(L)
    if albedo is not None:
        L = L * albedo[..., None]
    basis = _cached("basis", height, _basis_grid_np, L, xp)  # (HW, 9)
    out = L @ xp.permute_dims(basis, (1, 0))  # (..., C, HW)
    out = xp.reshape(out, tuple(out.shape[:-1]) + (height, 2 * height))
    return _to_layout(out, L, xp)


# --------------------------------------------------------------------------------------------
# the paper's diffuse convolution D(H, i)


def _hemisphere_weight(cos: Any, xp: Any) -> Any:
    """1 inside the hemisphere (``w . n > 0``), 1/2 on its boundary (within ``_TIE``), 0 outside."""
    return xp.astype(cos > _TIE, cos.dtype) + 0.5 * xp.astype(xp.abs(cos) <= _TIE, cos.dtype)


def _row_angles(height: int) -> tuple[np.ndarray, np.ndarray]:
    v = np.arange(height) + 0.5
    u = np.arange(2 * height) + 0.5
    phi, _ = angles_from_coords(u, np.zeros_like(u), height)
    _, theta = angles_from_coords(np.zeros_like(v), v, height)
    return phi - phi[0], theta  # azimuth offsets (2 pi k / W) and row elevations


@lru_cache(maxsize=2)
def _diffuse_operator_np(height: int) -> np.ndarray:
    """``D`` on the full grid as per-frequency row mixing ``M (W/2 + 1, H_out, H_in)``.

    The grid is uniform in azimuth, so the kernel ``s(w) max(w.n, 0) / K`` between output row
    ``o`` and input row ``i`` depends only on the column offset: a circulant (and even) matrix,
    diagonalised by the DFT along azimuth with real eigenvalues ``M[k, o, i]``. Then
    ``D = irfft_k(sum_i M[k, o, i] rfft(pano)[i, k])``: exact (up to float rounding).
    """
    dphi, theta = _row_angles(height)
    ct, st = np.cos(theta), np.sin(theta)
    s = solid_angle(height)[:, 0]
    M = np.empty((height + 1, height, height))
    for o in range(height):  # one output row at a time keeps the peak memory at O(H W)
        cos = ct[o] * ct[:, None] * np.cos(dphi)[None, :] + st[o] * st[:, None]  # (H_in, W offsets)
        k_i = np.sum(s[:, None] * _hemisphere_weight(cos, np))  # the paper's K_i (hemisphere solid angle)
        kernel = np.where(cos > 0, cos, 0.0) * s[:, None] / k_i
        M[:, o, :] = np.fft.rfft(kernel, axis=-1).real.T  # even in the offset: real spectrum
    return M


def _contiguous(x: Any) -> Any:
    return x.contiguous() if _is_torch(x) else x


def _diffuse_full(x: Any, xp: Any) -> Any:
    h = x.shape[-2]
    if h > MAX_EXACT_HEIGHT:
        raise InputError(
            f"diffuse convolution on the full grid supports H <= {MAX_EXACT_HEIGHT} (got {h}); "
            "pass height= to work on an area-downsampled panorama"
        )
    M = _cached("diffuse", h, _diffuse_operator_np, x, xp)
    lead = tuple(x.shape[:-2])
    # azimuth first and batch x channels last, so that every matmul operand (forward and
    # backward) is packed: a batched matmul on a permuted torch view is ~30x slower
    cols = _contiguous(xp.permute_dims(xp.reshape(x, (-1, h, 2 * h)), (2, 1, 0)))  # (W, H, N)
    spec = xp.fft.rfft(cols, axis=0)  # (K, H_in, N), K = W/2 + 1
    n = spec.shape[-1]
    mixed = M @ xp.concat([xp.real(spec), xp.imag(spec)], axis=-1)  # (K, H_out, 2N)
    out = xp.fft.irfft(mixed[..., :n] + 1j * mixed[..., n:], n=2 * h, axis=0)  # (W, H_out, N)
    out = xp.permute_dims(out, (2, 1, 0))
    return xp.reshape(out, lead + (h, 2 * h))


@lru_cache(maxsize=4)
def _grid_np(height: int) -> tuple[np.ndarray, np.ndarray]:
    return np.reshape(direction_grid(height), (-1, 3)), np.reshape(solid_angle(height), (-1,))


def _diffuse_at(x: Any, normals: Any, xp: Any) -> Any:
    h = x.shape[-2]
    dirs, s = _cached("grid", h, _grid_np, x, xp)  # (P, 3), (P,)
    lead = tuple(x.shape[:-2])
    flat = xp.reshape(x, lead + (h * 2 * h,))  # (..., C, P)
    nshape = tuple(normals.shape[:-1])
    n = xp.reshape(normals, (-1, 3))
    step = max(1, _CHUNK // dirs.shape[0])
    parts = []
    for start in range(0, n.shape[0], step):
        cos = n[start : start + step] @ xp.permute_dims(dirs, (1, 0))  # (m, P)
        k_i = _hemisphere_weight(cos, xp) @ s  # (m,)
        kernel = xp.where(cos > 0, cos, xp.zeros_like(cos)) * s / k_i[:, None]
        parts.append(flat @ xp.permute_dims(kernel, (1, 0)))  # (..., C, m)
    out = xp.concat(parts, axis=-1) if len(parts) > 1 else parts[0]
    return xp.reshape(out, tuple(out.shape[:-1]) + nshape)


def diffuse_convolution(pano: Any, normals: Any = None, *, height: int | None = None) -> Any:
    """The paper's diffuse convolution ``D(H, i)`` (§4.3, eq. 6), a cosine-weighted hemisphere mean.

    ``D(H, n) = (1 / K) sum_{w . n > 0} H(w) s(w) (w . n)`` with ``K = sum_{w . n > 0} s(w)`` the
    solid angle of the hemisphere's pixels, exactly as the paper writes it. ``K -> 2 pi``, so
    ``D = E / (2 pi)`` (irradiance over 2 pi): a constant map ``c`` gives ``c / 2``, a linear map
    ``H(w) = a . w`` gives ``(a . n) / 3``; :func:`sh_irradiance` (``kind="mean"``) is its
    second-order SH counterpart.

    Parameters
    ----------
    pano : array
        NumPy ``(..., H, 2H, C)`` or torch ``(..., C, H, 2H)``, linear radiance.
    normals : array ``(*S, 3)``, optional
        Unit normals at which to evaluate ``D`` (shared by every panorama of the batch), by the
        direct sum: cost ``O(#normals x h x 2h)`` (about 24 s for all 32768 directions of one
        128 x 256 panorama on 2 CPU threads; pass ``height=`` to integrate a smaller map), and under
        autograd the ``(#normals x h 2h)`` kernel is kept for the backward pass.
        Default: the panorama's own direction grid (the paper's sphere normal map ``N_ll``),
        evaluated exactly (same numbers as the direct sum, to float rounding) with a cached
        circulant operator: rfft along azimuth, one batched ``(H x H)`` matmul per frequency,
        inverse rfft (about 10 ms forward for 8 x 3 x 128 x 256 float32 on 2 CPU threads; the
        operator, ``(H + 1) H^2`` numbers, is cached per size, backend, device and dtype).
    height : int, optional
        Working resolution: the panorama is first resized to this height with the energy-preserving
        :func:`~solidkit.envmap.resample.resize`. With ``normals=None`` the result is on that grid.

    Returns
    -------
    ``normals=None``: a panorama in the backend's layout (``(..., h, 2h, C)`` / ``(..., C, h, 2h)``,
    ``h`` the working height). Otherwise NumPy ``(..., *S, C)`` / torch ``(..., C, *S)``.
    Differentiable in torch with respect to ``pano`` (and ``normals``).

    Examples
    --------
    >>> d = diffuse_convolution(np.full((32, 64, 3), 2.0, np.float32), height=8)
    >>> d.shape
    (8, 16, 3)
    >>> np.round(d[4, 8], 2)  # c / 2 = 1 for a constant sky c (0.99 on this coarse grid)
    array([0.99, 0.99, 0.99], dtype=float32)
    """
    x, xp = _working(pano, height)
    if normals is None:
        return _to_layout(_diffuse_full(x, xp), pano, xp)
    if normals.shape[-1] != 3:
        raise InputError(f"normals must have shape (..., 3), got {tuple(normals.shape)}")
    out = _diffuse_at(x, xp.astype(normals, x.dtype), xp)  # (..., C, *S)
    if _is_torch(pano):
        return out
    nd = normals.ndim - 1
    return xp.moveaxis(out, -nd - 1, -1)
