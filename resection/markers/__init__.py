"""The markers stage: from an image to linked 2-D / 3-D marker pairs.

Takes in an image (2-D float array), the 3-D markers (:class:`~resection.io.markers.MarkerSet`)
and an approximate camera or a hand-made linking; gives out sub-pixel candidates
(:class:`Candidates`: ``u, v, diameter, depth, merit, snr``) and the markers matched to them
(:class:`MatchResult`), ready for :mod:`resection.pose`.

- :mod:`~resection.markers.detect`: template merit, candidates, sub-pixel fit
  (compiled internals in ``_prep``, ``_peaks``, ``_starts``, ``_diskfit``, ``_diskmodel``);
- :mod:`~resection.markers.refine`: the compiled fit of a blurred, pixel-integrated disk;
- :mod:`~resection.markers.enhancement`: IR image enhancement before detection;
- :mod:`~resection.markers.match`: automatic matching (verified by a pose; right or refused);
- :mod:`~resection.markers.link`: linking by hand (``id,candidate`` files, numbered pictures);
- :mod:`~resection.markers.link_session`, :mod:`~resection.markers.link_server`: linking by
  clicking in a local page (``resection link --serve``), the pose solved live;
- :mod:`~resection.markers.in_image`: one image file read and its markers detected;
- :mod:`~resection.markers.from_image`: one image's linked markers and its pose;
- :mod:`~resection.markers.refind`: every target in view looked for again.
"""

from __future__ import annotations

from resection._lazy import attach

_EXPORTS: dict[str, str] = {
    "Candidates": ".detect",
    "ImagePoints": ".from_image",
    "LinkServer": ".link_server",
    "LinkSession": ".link_session",
    "MatchResult": ".match",
    "REASONS": ".refind",
    "RefindResult": ".refind",
    "clahe": ".enhancement",
    "detect_in_image": ".in_image",
    "detect_markers": ".detect",
    "draw_links": ".link",
    "enhance": ".enhancement",
    "estimate_noise": ".detect",
    "expected_diameter": ".in_image",
    "image_points": ".from_image",
    "marker_template": ".detect",
    "match_markers": ".match",
    "normalize_contrast": ".enhancement",
    "numbered": ".link",
    "open_session": ".link_session",
    "pose_from_image": ".from_image",
    "position_crb": ".detect",
    "read_candidates": ".detect",
    "read_links": ".link",
    "reference_frame": ".match",
    "refind_targets": ".refind",
    "refine_markers": ".refine",
    "serve_links": ".link_server",
    "subtract_background": ".enhancement",
    "suggest_links": ".link",
    "write_candidates": ".detect",
    "write_links": ".link",
}

__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = attach(__name__, _EXPORTS)
