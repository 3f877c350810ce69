"""The texture backends by name: what ``reconstruct_with_fit(backend="...")``,
:class:`facegeo.jobs.ReconstructOptions` and ``facegeo reconstruct --backend`` accept.

Each entry is a factory that imports its backend when called, so reading the names costs nothing
(the command line builds its parser from them) and the optional diffusion extra is imported only
when that backend is asked for. A module of its own: the backends import
:mod:`facegeo.texturing.backend`, so the registry that imports them cannot live there.
"""

from __future__ import annotations

from collections.abc import Callable
from os import PathLike

from facegeo.texturing.backend import TextureBackend

__all__ = ["BACKENDS"]


def _default_backend() -> TextureBackend:
    """:class:`facegeo.texturing.default.DefaultBackend` with its default settings."""
    from facegeo.texturing.default.backend import DefaultBackend

    return DefaultBackend()


def _diffusion_backend(weights: str | PathLike[str] | None = None) -> TextureBackend:
    """The diffusion backend from a weights folder (the optional [diffusion] extra)."""
    from facegeo.texturing.diffusion import require_extra

    require_extra()
    from facegeo.texturing.diffusion.backend import DiffusionBackend

    return DiffusionBackend.from_weights(weights)


#: Texture backends by name -> factory; ``diffusion``'s takes its weights folder.
BACKENDS: dict[str, Callable[..., TextureBackend]] = {"default": _default_backend, "diffusion": _diffusion_backend}
