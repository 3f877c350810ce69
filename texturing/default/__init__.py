"""The weight-free, deterministic default texture backend (:class:`DefaultBackend`), one concept a
module; every knob in one frozen :class:`DefaultSettings` (``DefaultBackend(settings=...)``).

Colour textures are sRGB in [0, 1], float32, S × S, image-style rows (see
:mod:`facegeo.texturing.backend`). Every step works on linear RGB:

* **De-lighting** (:mod:`.delighting`): the shading per texel, order-1 spherical harmonics of the
  camera-space normal fitted to the reliably seen skin and applied as shading^strength, the
  strength rising with how directional or how steep the fitted light is; where it is and the
  context has the posed mesh, one directional light with the posed mesh's cast shadows
  (:mod:`.directional_light`); the cast shadows and occlusion SH cannot explain; the gains bounded.
* **Reliability** (:mod:`.reliability`): how far each seen texel is trusted (visibility,
  foreshortening, distance to the unseen, the shading's steepness).
* **The skin's sheen** (:mod:`.sheen`): an environment's GGX reflection and the directional
  light's own sheen, taken out of the de-lit texture.
* **Highlights** (:mod:`.highlights`), **clipped texels** (:mod:`.clipping`) and **an occluder's
  fringe** (:mod:`.occluders`): left out of every fit and filled.
* **The light's colour** (:mod:`.light_colour`): from the skin locus and the photo's white
  references, divided out; under a sun and a sky of two colours, per texel by its ambient share,
  and the white reference read as lit at the eyes' share. A greyscale photo gets a generic skin
  chroma, and ``report["notes"]`` says so (the pipeline copies the notes into ``fit.json``).
* **The albedo's level** (:mod:`.albedo_level`): one factor from a skin-reflectance prior (the
  skin's place on the skin locus) and the white references (sclera, teeth), so that the albedo
  does not follow the photo's exposure; the relit texture keeps the photo's level.
* **inpaint** (:mod:`.fill`): a gradient-domain blend in log RGB, the low frequencies a screened
  Poisson problem on the mesh's vertices (continuous across UV seams and the mirror line), the fine
  detail the seen texel's own, the mirror's, or quilted from the seen skin (:mod:`.quilting`)
  with colour noise of its covariance per octave (:mod:`.noise`).
* **homogenise**: the filled texture divided by the shading and the light's colour.
* **materials** (:mod:`.materials`): albedo, displacement and normal from the albedo's fine
  detail, roughness and specular from facial-region priors and the highlight evidence.
* **upscale**: Lanczos (OpenCV ``INTER_LANCZOS4``).
* **Padding** (:func:`facegeo.texturing.image_filters.pad_outside`, every map): outside the UV
  islands the edge value over S/256 texels, then the map's median, flat (no streaks in texture
  viewers).

The stages are the methods of :class:`DefaultBackend` (:mod:`.backend`); the functions they call
take the settings passed down. The context's fitted SH lighting (``ctx.gamma``) is not used; the
model's texture (``ctx.mean_texture``) only when no texel is seen at all.

Names are imported lazily (:mod:`facegeo.lazy_exports`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from facegeo.lazy_exports import lazy_exports

_EXPORTS = {
    "DefaultBackend": "facegeo.texturing.default.backend",
    "DefaultSettings": "facegeo.texturing.default.settings",
    "DEFAULT_SETTINGS": "facegeo.texturing.default.settings",
}

__all__ = list(_EXPORTS)

if TYPE_CHECKING:
    from facegeo.texturing.default.backend import DefaultBackend
    from facegeo.texturing.default.settings import DEFAULT_SETTINGS, DefaultSettings


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
