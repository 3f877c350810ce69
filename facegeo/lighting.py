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
"""

from __future__ import annotations

import math

import numpy as np
import torch

__all__ = ["sh_basis", "sh_irradiance", "shade_vertices", "AMBIENT_WHITE", "N_SH"]

N_SH = 9
_A0, _A1, _A2 = math.pi, 2 * math.pi / math.sqrt(3.0), 2 * math.pi / math.sqrt(8.0)
_C0, _C1, _C2 = 1 / math.sqrt(4 * math.pi), math.sqrt(3.0) / math.sqrt(4 * math.pi), 3 * math.sqrt(5.0) / math.sqrt(12 * math.pi)

#: (3, 9) Deep3D's initial lighting (γ_0 = 0.8): uniform irradiance 0.8·√π/2 ≈ 0.709 per channel.
AMBIENT_WHITE = torch.zeros(3, N_SH)
AMBIENT_WHITE[:, 0] = 0.8


def sh_basis(normals: torch.Tensor | np.ndarray) -> torch.Tensor | np.ndarray:
    """The 9 Deep3D SH basis values of unit normals: (..., 3) -> (..., 9), same type and dtype. A
    NumPy array gives the tensor's values bit for bit (the same float operations in the same
    order), without torch's thread pool (whose start-up outweighs a few million products)."""
    if isinstance(normals, torch.Tensor):
        nx, ny, nz = normals.unbind(-1)
        one, stack = torch.ones_like(nx), torch.stack
    else:
        nx, ny, nz = np.moveaxis(np.asarray(normals), -1, 0)
        one, stack = np.ones_like(nx), np.stack
    return stack(
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


def sh_irradiance(normals: torch.Tensor, gamma: torch.Tensor) -> torch.Tensor:
    """Irradiance E of unit normals (..., V, 3) under γ (..., 3, 9) -> (..., V, 3) per channel."""
    return torch.einsum("...vk,...ck->...vc", sh_basis(normals), gamma)


def shade_vertices(albedo: torch.Tensor, normals: torch.Tensor, gamma: torch.Tensor) -> torch.Tensor:
    """Per-vertex colour = albedo (..., V, 3) linear × E(normals (..., V, 3), γ (..., 3, 9))."""
    return albedo * sh_irradiance(normals, gamma)
