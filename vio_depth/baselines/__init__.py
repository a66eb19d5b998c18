"""Baselines re-implemented for comparison: the paper's published code (:mod:`.paper_reference`).

=====================  ======================================================================
module                 job
=====================  ======================================================================
``paper_reference``    the published SfM rescaling (SIFT per pair, FLANN without ratio test,
                       unchecked triangulation, scikit-learn RANSAC, frames without a pair
                       dropped): :func:`iter_paper_reference` per frame
=====================  ======================================================================

scikit-learn is needed for the fit (extra ``baselines``) and imported only when a frame is fitted.
"""

from .paper_reference import (
    PAPER_REFERENCE_PRESETS,
    PaperReferenceResult,
    PaperReferenceSettings,
    PaperReferenceStatus,
    SklearnFit,
    choose_partner,
    default_disparity_source,
    fit_sklearn_ransac,
    iter_paper_reference,
    paper_reference_preset,
    process_frame,
    run_paper_reference,
    sequence_poses,
)

__all__ = [
    "PAPER_REFERENCE_PRESETS",
    "PaperReferenceResult",
    "PaperReferenceSettings",
    "PaperReferenceStatus",
    "SklearnFit",
    "choose_partner",
    "default_disparity_source",
    "fit_sklearn_ransac",
    "iter_paper_reference",
    "paper_reference_preset",
    "process_frame",
    "run_paper_reference",
    "sequence_poses",
]
