"""selfillum: self-illumination correction of luminescent-paint images.

Faces of a triangle mesh are the radiosity elements. ``B = E + diag(rho) F B`` links the
radiosity ``B`` (what a camera sees) to the emission ``E`` (what the paint emits).
"""

from .radiosity import SolveInfo, correct, forward
from .viewfactors import enforce_reciprocity, view_factors

__all__: list[str] = ["view_factors", "enforce_reciprocity", "forward", "correct", "SolveInfo"]
