"""SH lighting: the Deep3D basis against analytic values."""

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from facegeo.lighting import AMBIENT_WHITE, sh_basis, sh_irradiance, shade_vertices


def test_ambient_white_is_uniform():
    n = torch.nn.functional.normalize(torch.randn(100, 3, dtype=torch.float64), dim=-1)
    e = sh_irradiance(n, torch.tensor(AMBIENT_WHITE).double())
    np.testing.assert_allclose(e.numpy(), 0.8 * math.sqrt(math.pi) / 2, atol=1e-7)


def test_first_order_band_is_a_clamped_cosine_lobe_towards_the_camera():
    # Y_2 = a1·c1·n_z = (2π/√3)(√3/√(4π)) n_z = √π · n_z
    n = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]], dtype=torch.float64)
    y = sh_basis(n)
    np.testing.assert_allclose(y[:, 2].numpy(), [math.sqrt(math.pi), -math.sqrt(math.pi), 0.0], atol=1e-12)
    # Y_0 = π / √(4π) = √π / 2
    np.testing.assert_allclose(y[:, 0].numpy(), math.sqrt(math.pi) / 2, atol=1e-12)


def test_basis_is_orthogonal_over_the_sphere():
    # The 9 functions are scaled real SH: their Gram matrix over the sphere is diagonal.
    rng = np.random.default_rng(0)
    n = torch.from_numpy(rng.normal(size=(400_000, 3)))
    n = torch.nn.functional.normalize(n, dim=-1)
    y = sh_basis(n)
    gram = (y.T @ y / len(n)).numpy()
    off = gram - np.diag(np.diag(gram))
    assert np.abs(off).max() < 0.02 * np.abs(np.diag(gram)).max()


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_numpy_basis_is_the_tensor_basis_bit_for_bit(dtype):
    """The texture stage computes the basis of a million texel normals on NumPy arrays: the same
    values as the tensor path, to the last bit (its maps must not change)."""
    n = np.random.default_rng(1).normal(size=(2, 50_001, 3)).astype(dtype)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    y = sh_basis(n)
    assert isinstance(y, np.ndarray) and y.dtype == dtype and y.shape == (2, 50_001, 9)
    np.testing.assert_array_equal(y.view(np.uint8), sh_basis(torch.from_numpy(n)).numpy().view(np.uint8))


@settings(max_examples=20, deadline=None)
@given(st.lists(st.floats(-1, 1), min_size=27, max_size=27))
def test_irradiance_is_linear_in_gamma(values):
    n = torch.nn.functional.normalize(torch.randn(10, 3, dtype=torch.float64), dim=-1)
    g = torch.tensor(values, dtype=torch.float64).reshape(3, 9)
    e = sh_irradiance(n, g)
    np.testing.assert_allclose(e.numpy(), (sh_basis(n) @ g.T).numpy(), atol=1e-12)
    np.testing.assert_allclose(sh_irradiance(n, 2 * g).numpy(), 2 * e.numpy(), atol=1e-12)


def test_shade_vertices_batched():
    albedo = torch.full((2, 5, 3), 0.5)
    n = torch.tensor([0.0, 0.0, 1.0]).expand(2, 5, 3)
    out = shade_vertices(albedo, n, torch.tensor(AMBIENT_WHITE).expand(2, 3, 9))
    assert out.shape == (2, 5, 3)
    assert out.numpy() == pytest.approx(0.5 * 0.8 * math.sqrt(math.pi) / 2)


def test_numpy_and_torch_give_the_same_basis_and_irradiance():
    rng = np.random.default_rng(3)
    n = rng.normal(size=(50, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    gamma = rng.normal(size=(3, 9))
    basis = sh_basis(n)
    assert isinstance(basis, np.ndarray) and basis.dtype == np.float64 and basis.shape == (50, 9)
    np.testing.assert_allclose(basis, sh_basis(torch.from_numpy(n)).numpy(), rtol=0, atol=1e-15)
    e = sh_irradiance(n, gamma)
    assert isinstance(e, np.ndarray)
    np.testing.assert_allclose(e, sh_irradiance(torch.from_numpy(n), torch.from_numpy(gamma)).numpy(), atol=1e-13)
    assert sh_basis(n.astype(np.float32)).dtype == np.float32


def test_ambient_white_cannot_be_changed_by_a_caller():
    with pytest.raises(ValueError):
        AMBIENT_WHITE[0, 0] = 1.0
