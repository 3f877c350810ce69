"""Second-order spherical-harmonics lighting in the Deep3D / Hifi3D convention.

Per-vertex colour = albedo × E(n), with the irradiance E(n) = Σ_k γ_{c,k} · Y_k(n) for each colour
channel c and the 9 basis functions Y_k of Deep3DFaceRecon (Lambertian convolution constants
a_k folded in):

    a0 = π, a1 = 2π/√3, a2 = 2π/√8;  c0 = 1/√(4π), c1 = √3/√(4π), c2 = 3√5/√(12π)
    Y = [a0·c0, −a1·c1·n_y, a1·c1·n_z, −a1·c1·n_x, a2·c2·n_x·n_y, −a2·c2·n_y·n_z,
         a2·c2/(2√3)·(3n_z² − 1), −a2·c2·n_x·n_z, a2·c2/2·(n_x² − n_y²)]

Normals are unit vectors in camera space (OpenGL axes, +Z towards the camera). Deep3D adds 0.8 to
γ_{c,0} of its network output; facegeo stores the total coefficient (no hidden offset), so
γ = AMBIENT_WHITE (Deep3D's zero output) gives the uniform irradiance E ≡ 0.8·√π/2 ≈ 0.709.

The functions take NumPy arrays or torch tensors and answer in the same type and dtype
(differentiable for tensors); torch is not imported here (:mod:`facegeo.array_namespace`).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from facegeo.array_namespace import array_namespace

if TYPE_CHECKING:
    import torch

__all__ = ["sh_basis", "sh_irradiance", "shade_vertices", "AMBIENT_WHITE", "N_SH"]

N_SH = 9
_A0, _A1, _A2 = math.pi, 2 * math.pi / math.sqrt(3.0), 2 * math.pi / math.sqrt(8.0)
_C0, _C1, _C2 = 1 / math.sqrt(4 * math.pi), math.sqrt(3.0) / math.sqrt(4 * math.pi), 3 * math.sqrt(5.0) / math.sqrt(12 * math.pi)

#: (3, 9) float32, read-only: Deep3D's initial lighting (γ_0 = 0.8), uniform irradiance
#: 0.8·√π/2 ≈ 0.709 per channel (``torch.from_numpy`` for a tensor).
AMBIENT_WHITE = np.zeros((3, N_SH), np.float32)
AMBIENT_WHITE[:, 0] = 0.8
AMBIENT_WHITE.setflags(write=False)


def sh_basis(normals: np.ndarray | torch.Tensor) -> np.ndarray | torch.Tensor:
    """The 9 Deep3D SH basis values of unit normals: (..., 3) -> (..., 9), same type and dtype."""
    xp = array_namespace(normals)
    nx, ny, nz = normals[..., 0], normals[..., 1], normals[..., 2]
    one = xp.ones_like(nx)
    return xp.stack(
        [
            _A0 * _C0 * one,
            -_A1 * _C1 * ny,
            _A1 * _C1 * nz,
            -_A1 * _C1 * nx,
            _A2 * _C2 * nx * ny,
            -_A2 * _C2 * ny * nz,
            _A2 * _C2 / (2 * math.sqrt(3.0)) * (3 * nz * nz - 1),
            -_A2 * _C2 * nx * nz,
            _A2 * _C2 / 2 * (nx * nx - ny * ny),
        ],
        -1,
    )


def sh_irradiance(normals: np.ndarray | torch.Tensor, gamma: np.ndarray | torch.Tensor) -> np.ndarray | torch.Tensor:
    """Irradiance E of unit normals (..., V, 3) under γ (..., 3, 9) -> (..., V, 3) per channel
    (both arguments of one type)."""
    return array_namespace(normals).einsum("...vk,...ck->...vc", sh_basis(normals), gamma)


def shade_vertices(albedo: np.ndarray | torch.Tensor, normals: np.ndarray | torch.Tensor,
                   gamma: np.ndarray | torch.Tensor) -> np.ndarray | torch.Tensor:
    """Per-vertex colour = albedo (..., V, 3) linear × E(normals (..., V, 3), γ (..., 3, 9))."""
    return albedo * sh_irradiance(normals, gamma)
