"""selfillum: self-illumination correction of luminescent-paint images.

Faces of a triangle mesh are the radiosity elements. ``B = E + diag(rho) F B`` links the
radiosity ``B`` (what a camera sees) to the emission ``E`` (what the paint emits).

* :func:`view_factors`: form factors ``F`` by Embree ray casting (sparse, N K entries);
* :func:`forward`: ``E -> B``; :func:`correct`: ``B -> E`` (all or part of the faces seen);
* :func:`correct_image`: a camera image corrected pixel by pixel;
* :mod:`selfillum.corner`: the corner case end to end; :mod:`selfillum.render`: Mitsuba
  renders (the independent reference).
"""

from .correct_image import ImageCorrection, correct_image
from .radiosity import SolveInfo, correct, forward
from .viewfactors import enforce_reciprocity, view_factors

__all__: list[str] = [
    "view_factors",
    "enforce_reciprocity",
    "forward",
    "correct",
    "SolveInfo",
    "correct_image",
    "ImageCorrection",
]
