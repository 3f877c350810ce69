"""Analysis-by-synthesis fitting of the morphable model to one photo (CPU, float32).

Modules, one concept each:

* :mod:`~facegeo.fitting.result`: :class:`Fit` (the result) and :class:`Fitter` (the seam);
  data only, no solver imports.
* :mod:`~facegeo.fitting.priors`: :class:`FitPriors`, the schedule, the correctives.
* :mod:`~facegeo.fitting.landmark_problem`: residuals and Jacobian of the landmark term.
* :mod:`~facegeo.fitting.landmark_fit`: :func:`fit_landmarks`, the MAP landmark fit.
* :mod:`~facegeo.fitting.photometric`: albedo and SH lighting from the photo.
* :mod:`~facegeo.fitting.checks`: what keeps a wrong fit from being reported.
* :mod:`~facegeo.fitting.photo_fit`: :func:`fit`, photo to :class:`Fit`.
* :mod:`~facegeo.fitting.shared_identity`: :func:`fit_photos`, several photos of one person to
  one identity (pose and expression per photo).

Names are exported lazily (:mod:`facegeo.lazy_exports`): importing :class:`Fit` does not import
OpenCV or the solver.
"""

from typing import TYPE_CHECKING

from facegeo.lazy_exports import lazy_exports

_EXPORTS = {
    "Fit": ".result",
    "Fitter": ".result",
    "FitPriors": ".priors",
    "DEFAULT_PRIORS": ".priors",
    "LandmarkStage": ".priors",
    "LANDMARK_SCHEDULE": ".priors",
    "CORRECTIVES": ".priors",
    "PHOTOMETRIC_REGULARISATION": ".photometric",
    "fit_landmarks": ".landmark_fit",
    "fit": ".photo_fit",
    "fit_photos": ".shared_identity",
}
__all__ = list(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

if TYPE_CHECKING:
    from facegeo.fitting.landmark_fit import fit_landmarks
    from facegeo.fitting.photo_fit import fit
    from facegeo.fitting.photometric import PHOTOMETRIC_REGULARISATION
    from facegeo.fitting.shared_identity import fit_photos
    from facegeo.fitting.priors import CORRECTIVES, DEFAULT_PRIORS, LANDMARK_SCHEDULE, FitPriors, LandmarkStage
    from facegeo.fitting.result import Fit, Fitter
